"""The historian's queryable ``edge/history/**``: a selector in, one JSON answer out.

``edge/history/<what>?<parameters>`` with ``what`` one of records, alarms (the open ones), fleet, gaps,
daily, status and the parameters of :mod:`edge_monitor.historian.query_spec` (``robot``, ``joint``,
``kind``, ``since``, ``until``, ``limit``, ``cursor``, ``rank``, ``stale``), e.g.
``edge/history/records?robot=r1;joint=2;kind=symptom;since=7d;limit=500``. The reply comes on the key
asked for, encoding ``application/json`` (schemas: ``edge-monitor schema history|fleet``). A malformed
selector (unknown question or parameter, a value out of range) gets ``reply_err`` with
``{"error": "…", "refused": true}`` naming the parameter (``"refused": false``: a good question the historian
cannot answer now, its database unavailable or damaged); a robot never heard of gets an empty answer that says so
(``robot_known: false``). Queries that cover other keys (``edge/**``) are answered only for the keys
of the history: an agent's state query is never answered here.

Zenoh calls :meth:`HistoryQueryable._on_query` on the thread that also delivers the historian's records and
status questions, so it never waits there: a question is handed to a waiter thread, at most
``max_waiting`` at once; more get a counted ``busy`` reply (``"refused": false, "busy": true``: retry in a
few seconds), and ``edge/history/status`` is answered at once, however many questions wait.
"""

from __future__ import annotations

import logging
import threading
import time
from concurrent.futures import CancelledError, Future, ThreadPoolExecutor
from typing import Any, Callable

import zenoh

from edge_monitor.historian.database import DatabaseError
from edge_monitor.historian.queries import answer
from edge_monitor.historian.query_spec import ANSWERS, QueryError, query_of
from edge_monitor.records import to_json

log = logging.getLogger(__name__)

HISTORY_PREFIX = "edge/history"
ANSWER_TIMEOUT_S = 20.0
MAX_WAITING = 16          # questions handed over and not yet answered; more get a "busy, retry" reply


def history_key(what: str) -> str:
    return f"{HISTORY_PREFIX}/{what}"


class HistoryQueryable:
    """Declares ``edge/history/**``; ``submit(ask)`` runs ``ask(connection, online)`` off Zenoh's thread and
    returns a Future; ``status()`` answers ``edge/history/status``. Counters: ``answered``, ``refused``
    (error replies), ``busy`` (questions turned away because ``max_waiting`` were waiting)."""

    def __init__(self, session: zenoh.Session, submit: Callable[[Callable[..., Any]], Future],
                 status: Callable[[], dict[str, Any]], max_waiting: int = MAX_WAITING) -> None:
        if max_waiting < 1:
            raise ValueError(f"max_waiting={max_waiting} must be >= 1")
        self.submit = submit
        self.status = status
        self.max_waiting = int(max_waiting)
        self.answered = 0
        self.refused = 0
        self.busy = 0
        self._waiting = 0
        self._lock = threading.Lock()
        self._waiters = ThreadPoolExecutor(max_workers=self.max_waiting, thread_name_prefix="historian-answer")
        self._queryable = session.declare_queryable(f"{HISTORY_PREFIX}/**", self._on_query)

    def counters(self) -> dict[str, int]:
        """The questions answered, refused, turned away busy, and waiting now (for the status)."""
        with self._lock:
            return {"answered": self.answered, "refused": self.refused, "busy": self.busy, "waiting": self._waiting}

    def _on_query(self, query: zenoh.Query) -> None:
        """On Zenoh's thread: never waits for the database (a burst of questions must not hold it)."""
        selector = zenoh.KeyExpr(str(query.key_expr))
        asked = [what for what in ANSWERS if zenoh.KeyExpr(history_key(what)).intersects(selector)]
        if len(asked) != 1:
            if str(query.key_expr).startswith(HISTORY_PREFIX):
                self._error(query, f"ask one question: edge/history/<{'|'.join(ANSWERS)}>?parameters "
                                   f"(got {str(query.key_expr)[:80]})")
            return
        what = asked[0]
        try:
            question = query_of(what, _parameters(query))
        except QueryError as exc:
            self._error(query, str(exc), history_key(what))
            return
        if what == "status":
            self._reply(query, history_key(what), {"schema": 1, "answer": "status", **self.status()})
            return
        self._hand_over(query, history_key(what), lambda conn, online: answer(conn, question, online=online))

    def _hand_over(self, query: zenoh.Query, key: str, ask: Callable[..., Any]) -> None:
        """Queue ``ask`` for the database and a waiter to reply; a "busy, retry" reply when too many wait."""
        with self._lock:
            full = self._waiting >= self.max_waiting
            if not full:
                self._waiting += 1
        if full:
            self._busy(query, key, f"{self.max_waiting} questions are waiting for an answer")
            return
        deadline = time.monotonic() + ANSWER_TIMEOUT_S
        future: Future | None = None
        try:
            future = self.submit(ask)
            self._waiters.submit(self._deliver, query, key, future, deadline)
        except RuntimeError:               # the historian is stopping: its pools take no more work
            if future is not None:
                future.cancel()
            self._done()
            self._error(query, "the historian is stopping: ask again when it is back", key, refused=False)

    def _busy(self, query: zenoh.Query, key: str, why: str) -> None:
        """The "busy, retry" reply, counted in ``busy`` (logged at the 1st, 100th, every 10 000th)."""
        with self._lock:
            self.busy += 1
            busy = self.busy
        if busy in (1, 100) or busy % 10_000 == 0:
            log.warning("history questions come faster than they are answered: %d turned away busy so far "
                        "(%d waiting at most)", busy, self.max_waiting)
        self._error(query, f"the historian is busy: {why}; retry in a few seconds (or ask fewer at once)", key,
                    refused=False, counted=False, busy=True)

    def _deliver(self, query: zenoh.Query, key: str, future: Future, deadline: float) -> None:
        """On a waiter thread: the answer, or a clear error by the deadline."""
        try:
            body = future.result(timeout=max(0.0, deadline - time.monotonic()))
        except DatabaseError as exc:
            self._error(query, f"the history's database is unavailable: {exc}", key, refused=False)
        except TimeoutError:
            if future.cancel():            # not started: it waited behind other questions, and never runs
                self._busy(query, key, f"no answer within {ANSWER_TIMEOUT_S:g} s (other questions came first)")
            else:
                self._error(query, f"no answer within {ANSWER_TIMEOUT_S:g} s: narrow the question (robot, kind, "
                                   "since/until, a smaller limit)", key, refused=False)
        except CancelledError:
            self._error(query, "the historian is stopping: ask again when it is back", key, refused=False)
        except Exception as exc:       # never raise into a thread's void; say what went wrong
            log.exception("history query %s failed", query.selector)
            self._error(query, f"the historian failed on this question: {exc}", key, refused=False)
        else:
            self._reply(query, key, body)
        finally:
            self._done()
            _finish(query)

    def _done(self) -> None:
        with self._lock:
            self._waiting -= 1

    def _reply(self, query: zenoh.Query, key: str, body: dict[str, Any]) -> None:
        try:
            query.reply(key, to_json(body), encoding=zenoh.Encoding.APPLICATION_JSON)
            with self._lock:
                self.answered += 1
        except Exception as exc:
            log.warning("history reply on %s failed: %s", key, exc)

    def _error(self, query: zenoh.Query, message: str, key: str = HISTORY_PREFIX, refused: bool = True,
               counted: bool = True, busy: bool = False) -> None:
        """``reply_err``: ``refused`` the question as asked (a client's usage error), else unanswerable now
        (``busy``: try again soon); ``counted`` in ``refused``."""
        if counted:
            with self._lock:
                self.refused += 1
        body: dict[str, Any] = {"error": message, "key": key, "refused": refused}
        if busy:
            body["busy"] = True
        try:
            query.reply_err(to_json(body), encoding=zenoh.Encoding.APPLICATION_JSON)
        except Exception as exc:
            log.debug("history error reply failed: %s", exc)

    def close(self) -> None:
        """Stop taking questions; those still waiting are answered (or told the historian stops) by their
        waiters once the database pool ends."""
        try:
            self._queryable.undeclare()
        except Exception as exc:
            log.debug("undeclare failed: %s", exc)
        self._waiters.shutdown(wait=False)

    def drain(self) -> None:
        """Wait for the waiters (after the database pool ended: each replies at once)."""
        self._waiters.shutdown(wait=True)


def _finish(query: zenoh.Query) -> None:
    """Tell the asker no more replies come (else that happens only when Python frees the query)."""
    try:
        query.drop()
    except Exception as exc:
        log.debug("finishing a history query failed: %s", exc)


def _parameters(query: zenoh.Query) -> dict[str, str]:
    """The selector's parameters as a dict (zenoh.Parameters iterates as (name, value) pairs)."""
    found: Any = query.parameters
    return {str(name): str(value) for name, value in found}
