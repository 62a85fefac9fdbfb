"""Asking the history: over Zenoh (``edge/history/<what>?…``, the historian answers) or straight from the
database (``--db``), the same questions and the same answers; :func:`pages` follows the cursor of a
records answer until the records wanted are there."""

from __future__ import annotations

import dataclasses
import json
from typing import Any, Callable, Iterator

import zenoh

from edge_monitor.historian.database import Connection
from edge_monitor.historian.queries import answer
from edge_monitor.historian.query_spec import MAX_LIMIT, Cursor, HistoryQuery, parameters_of
from edge_monitor.historian.zenoh_answers import history_key

DEFAULT_TIMEOUT_S = 10.0

Ask = Callable[[HistoryQuery], dict[str, Any]]


class HistoryUnavailable(RuntimeError):
    """No historian answered (none running, not reachable, or the access control hides it)."""


class HistoryRefused(ValueError):
    """The historian answered that the question cannot be answered as asked (its message)."""


def selector_of(query: HistoryQuery) -> str:
    parameters = ";".join(f"{k}={v}" for k, v in parameters_of(query).items())
    return f"{history_key(query.what)}?{parameters}"


def zenoh_asker(session: zenoh.Session, timeout_s: float = DEFAULT_TIMEOUT_S) -> Ask:
    """Ask the historian over Zenoh: the first reply counts (several historians on one database agree)."""
    def ask(query: HistoryQuery) -> dict[str, Any]:
        selector = selector_of(query)
        for reply in session.get(selector, timeout=timeout_s):
            if reply.ok is not None:
                return json.loads(reply.ok.payload.to_string())
            text = reply.err.payload.to_string() if reply.err is not None else ""
            try:
                parsed = json.loads(text)
                error, refused = parsed.get("error"), parsed.get("refused", True)
            except (ValueError, AttributeError):
                error, refused = text[:300], True
            if not refused:             # the question was fine; the historian could not answer it now
                raise HistoryUnavailable(f"the historian could not answer {selector}: {error}")
            raise HistoryRefused(f"the historian refused {selector}: {error}")
        raise HistoryUnavailable(f"no historian answered {history_key(query.what)} within {timeout_s:g} s: is "
                                 "`edge-monitor historian` running and connected to the same router (and allowed "
                                 "to answer by its access control)?")
    return ask


def database_asker(conn: Connection) -> Ask:
    """Ask the database directly (no liveliness: ``online`` is null in fleet answers)."""
    return lambda query: answer(conn, query)


def pages(ask: Ask, query: HistoryQuery, wanted: int) -> Iterator[dict[str, Any]]:
    """Answers of ``query`` page after page (pages of at most 1 000) until ``wanted`` records came or
    none are left; the last answer yielded says ``truncated`` when more were left."""
    got = 0
    while True:
        page = dataclasses.replace(query, limit=max(1, min(MAX_LIMIT, wanted - got)))
        body = ask(page)
        got += int(body.get("count") or 0)
        more = bool(body.get("next")) and got < wanted
        if more:
            body = {**body, "truncated": False}
        yield body
        if not more:
            return
        query = dataclasses.replace(query, cursor=Cursor.parse(body["next"]))
