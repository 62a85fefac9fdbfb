"""Gaps: cycles missing from a joint's stored symptoms, as ranges.

In the order the records were made (their time, then id), a symptom whose cycle is more than one past
the previous one of the same joint leaves the cycles between them missing. That is what the database
lacks; whether the agent ever published them is another matter (it was stopped, or the controller
skipped numbers): ``edge-monitor historian import`` of the agent's JSONL file fills what it had. A cycle
number that goes back (a controller that restarted its count) starts a new run and is no gap.
"""

from __future__ import annotations

from typing import Any

from edge_monitor.historian.database import Connection
from edge_monitor.historian.query_spec import HistoryQuery
from edge_monitor.historian.times import utc_of_seconds

_GAPS = """SELECT robot, joint, previous, cycle, previous_at, at FROM (
    SELECT robot, joint, cycle, at,
           LAG(cycle) OVER (PARTITION BY robot, joint ORDER BY at, id) AS previous,
           LAG(at) OVER (PARTITION BY robot, joint ORDER BY at, id) AS previous_at
    FROM records WHERE kind = 'symptom' AND {where}) AS ordered
  WHERE cycle > previous + 1 ORDER BY robot, joint, at LIMIT ?"""


def find_gaps(conn: Connection, robot: str | None = None, joint: int | None = None, since: float | None = None,
              until: float | None = None, limit: int = 1000) -> list[dict[str, Any]]:
    """The missing cycle ranges (at most ``limit``), each ``{"robot", "joint", "first", "last", "missing",
    "after_utc", "before_utc"}`` (the first and last missing cycle, and the times of the records around)."""
    clauses, params = ["1 = 1"], []
    for column, op, value in (("robot", "=", robot), ("joint", "=", joint), ("at", ">=", since), ("at", "<", until)):
        if value is not None:
            clauses.append(f"{column} {op} ?")
            params.append(value)
    rows = conn.rows(_GAPS.format(where=" AND ".join(clauses)), (*params, limit))
    return [{"robot": r, "joint": j, "first": previous + 1, "last": cycle - 1, "missing": cycle - previous - 1,
             "after_utc": utc_of_seconds(previous_at), "before_utc": utc_of_seconds(at)}
            for r, j, previous, cycle, previous_at, at in rows]


def gaps_answer(conn: Connection, query: HistoryQuery) -> dict[str, Any]:
    found = find_gaps(conn, query.robot, query.joint, query.since, query.until, query.limit + 1)
    page = found[:query.limit]
    return {"gaps": page, "missing": sum(g["missing"] for g in page), "count": len(page),
            "truncated": len(found) > query.limit, "next": None}


def describe_gaps(gaps: list[dict[str, Any]], shown: int = 10) -> str:
    """One line per gap (at most ``shown``) for logs and command output."""
    lines = [f"{g['robot']} joint {g['joint']}: cycles {g['first']}–{g['last']} missing ({g['missing']})"
             for g in gaps[:shown]]
    if len(gaps) > shown:
        lines.append(f"… and {len(gaps) - shown} more gap(s)")
    return "\n".join(lines)
