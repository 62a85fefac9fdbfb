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
"""

from __future__ import annotations

import logging
from concurrent.futures import Future
from typing import Any, Callable

import zenoh

from edge_monitor.historian.database import DatabaseError
from edge_monitor.historian.queries import answer
from edge_monitor.historian.query_spec import ANSWERS, QueryError, query_of
from edge_monitor.records import to_json

log = logging.getLogger(__name__)

HISTORY_PREFIX = "edge/history"
ANSWER_TIMEOUT_S = 20.0


def history_key(what: str) -> str:
    return f"{HISTORY_PREFIX}/{what}"


class HistoryQueryable:
    """Declares ``edge/history/**``; ``submit(ask)`` runs ``ask(connection, online)`` off Zenoh's thread and
    returns a Future; ``status()`` answers ``edge/history/status``."""

    def __init__(self, session: zenoh.Session, submit: Callable[[Callable[..., Any]], Future],
                 status: Callable[[], dict[str, Any]]) -> None:
        self.submit = submit
        self.status = status
        self.answered = 0
        self.refused = 0
        self._queryable = session.declare_queryable(f"{HISTORY_PREFIX}/**", self._on_query)

    def _on_query(self, query: zenoh.Query) -> None:
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
        future = self.submit(lambda conn, online: answer(conn, question, online=online))
        try:
            body = future.result(timeout=ANSWER_TIMEOUT_S)
        except DatabaseError as exc:
            self._error(query, f"the history's database is unavailable: {exc}", history_key(what), refused=False)
            return
        except TimeoutError:
            self._error(query, f"no answer within {ANSWER_TIMEOUT_S:g} s: narrow the question (robot, kind, "
                               "since/until, a smaller limit)", history_key(what), refused=False)
            return
        except Exception as exc:       # never raise into Zenoh; say what went wrong
            log.exception("history query %s failed", query.selector)
            self._error(query, f"the historian failed on this question: {exc}", history_key(what), refused=False)
            return
        self._reply(query, history_key(what), body)

    def _reply(self, query: zenoh.Query, key: str, body: dict[str, Any]) -> None:
        try:
            query.reply(key, to_json(body), encoding=zenoh.Encoding.APPLICATION_JSON)
            self.answered += 1
        except Exception as exc:
            log.warning("history reply on %s failed: %s", key, exc)

    def _error(self, query: zenoh.Query, message: str, key: str = HISTORY_PREFIX, refused: bool = True) -> None:
        """``reply_err``: ``refused`` the question as asked (a client's usage error), else unanswerable now."""
        self.refused += 1
        try:
            query.reply_err(to_json({"error": message, "key": key, "refused": refused}),
                            encoding=zenoh.Encoding.APPLICATION_JSON)
        except Exception as exc:
            log.debug("history error reply failed: %s", exc)

    def close(self) -> None:
        try:
            self._queryable.undeclare()
        except Exception as exc:
            log.debug("undeclare failed: %s", exc)


def _parameters(query: zenoh.Query) -> dict[str, str]:
    """The selector's parameters as a dict (zenoh.Parameters iterates as (name, value) pairs)."""
    found: Any = query.parameters
    return {str(name): str(value) for name, value in found}
