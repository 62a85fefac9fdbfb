"""Answers to history questions, read from the database in one read transaction each.

Every answer is a JSON object (schemas ``edge-monitor schema history|fleet``): the question as it was
understood (``query``), the items, ``count``, ``truncated`` (more matched than ``limit``) with ``next``
(the cursor of the next page), and ``robot_known`` / ``message`` when the robot asked for has never
been heard of. Records come back as published, with ``kind`` in front.
"""

from __future__ import annotations

import time
from typing import Any

from edge_monitor.historian.database import Connection, stored_record
from edge_monitor.historian.fleet import fleet_answer
from edge_monitor.historian.query_spec import Cursor, HistoryQuery
from edge_monitor.historian.times import DAY_S, utc_of_seconds

ANSWER_SCHEMA = 1
_KNOWN_ROBOTS_SHOWN = 20


def answer(conn: Connection, query: HistoryQuery, now: float | None = None,
           online: set[str] | None = None) -> dict[str, Any]:
    """The answer to ``query`` (``online``: robots whose liveliness token is up, when the caller knows)."""
    now = time.time() if now is None else now
    with conn.transaction(write=False):
        if query.what == "fleet":
            body = fleet_answer(conn, query, now, online)
        elif query.what == "alarms":
            body = _open_alarms(conn, query)
        elif query.what == "daily":
            body = _daily(conn, query)
        elif query.what == "gaps":
            from edge_monitor.historian.gaps import gaps_answer
            body = gaps_answer(conn, query)
        else:
            body = _records(conn, query)
        if query.robot is not None and not body.get("count"):
            body.update(_robot_known(conn, query.robot))
    return {"schema": ANSWER_SCHEMA, "answer": query.what, "query": query.describe(), **body}


def _filters(query: HistoryQuery, time_column: str = "at") -> tuple[list[str], list[Any]]:
    where: list[str] = ["1 = 1"]
    params: list[Any] = []
    if query.robot is not None:
        where.append("robot = ?")
        params.append(query.robot)
    if query.joint is not None:
        where.append("joint = ?")
        params.append(query.joint)
    if query.since is not None:
        where.append(f"{time_column} >= ?")
        params.append(query.since if time_column == "at" else int(query.since // DAY_S))
    if query.until is not None:
        where.append(f"{time_column} < ?")
        params.append(query.until if time_column == "at" else int(-(-query.until // DAY_S)))
    return where, params


def as_published(kind: str, body: str) -> dict[str, Any]:
    """A stored record with ``kind`` in front: the kind it was stored as (from its key), never a "kind"
    field of the record's own."""
    record = stored_record(body)
    return {"kind": kind, **{name: value for name, value in record.items() if name != "kind"}}


def _records(conn: Connection, query: HistoryQuery) -> dict[str, Any]:
    where, params = _filters(query)
    if query.kinds:
        where.append(f"kind IN ({', '.join('?' for _ in query.kinds)})")
        params.extend(query.kinds)
    if query.cursor is not None:
        where.append("(at > ? OR (at = ? AND id > ?))")
        params.extend([query.cursor.at, query.cursor.at, query.cursor.id])
    rows = conn.rows(f"SELECT id, kind, at, body FROM records WHERE {' AND '.join(where)} ORDER BY at, id LIMIT ?",
                     (*params, query.limit + 1))
    page = rows[:query.limit]
    truncated = len(rows) > query.limit
    items = [as_published(kind, body) for _id, kind, _at, body in page]
    return {"records": items, "count": len(items), "truncated": truncated,
            "next": Cursor(page[-1][2], page[-1][0]).text() if truncated else None}


def _open_alarms(conn: Connection, query: HistoryQuery) -> dict[str, Any]:
    """The newest record of every open fault, by robot, joint and fault id."""
    where, params = _filters(query)
    where.append("is_open = 1")
    rows = conn.rows(f"SELECT fault, body FROM faults WHERE {' AND '.join(where)} "
                     "ORDER BY robot, joint, fault LIMIT ?", (*params, query.limit + 1))
    items = [as_published("alarm", body) for _fault, body in rows[:query.limit]]
    return {"records": items, "count": len(items), "truncated": len(rows) > query.limit, "next": None}


def _daily(conn: Connection, query: HistoryQuery) -> dict[str, Any]:
    """Daily summaries of thinned days (per joint: records, cycles, wear min/mean/max, alarm records)."""
    where, params = _filters(query, "day")
    rows = conn.rows("SELECT robot, joint, day, records, first_cycle, last_cycle, wear_min, wear_max, wear_sum, "
                     f"wear_n, alarm_records FROM daily WHERE {' AND '.join(where)} ORDER BY day, robot, joint "
                     "LIMIT ?", (*params, query.limit + 1))
    items = [{"kind": "daily", "robot": r, "joint": j, "day": str(utc_of_seconds(d * DAY_S))[:10], "records": n,
              "first_cycle": c0, "last_cycle": c1,
              "wear": {"min": w0, "max": w1, "mean": None if not wn else ws / wn}, "alarm_records": a}
             for r, j, d, n, c0, c1, w0, w1, ws, wn, a in rows[:query.limit]]
    return {"records": items, "count": len(items), "truncated": len(rows) > query.limit, "next": None}


def _robot_known(conn: Connection, robot: str) -> dict[str, Any]:
    """For an empty answer about ``robot``: whether it was ever heard of, and which robots are."""
    if conn.rows("SELECT 1 FROM agents WHERE robot = ?", (robot,)) or \
            conn.rows("SELECT 1 FROM records WHERE robot = ? LIMIT 1", (robot,)):
        return {"robot_known": True}
    known = [r for (r,) in conn.rows("SELECT robot FROM agents UNION SELECT robot FROM joints ORDER BY robot LIMIT ?",
                                     (_KNOWN_ROBOTS_SHOWN + 1,))]
    shown = ", ".join(known[:_KNOWN_ROBOTS_SHOWN]) + (", …" if len(known) > _KNOWN_ROBOTS_SHOWN else "")
    return {"robot_known": False,
            "message": f"no robot {robot!r} in the history" + (f"; known robots: {shown}" if known else
                                                              "; the history holds no robot yet")}
