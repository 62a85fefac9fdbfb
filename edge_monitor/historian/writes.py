"""Storing rows exactly once, with the tables the fleet questions read kept up to date in the same
transaction.

``INSERT … ON CONFLICT (robot, kind, ident) DO NOTHING``: a row whose identity is stored already changes
nothing and is counted as a duplicate — apart from a friction curve (each comes twice: in its symptom and
as the friction sample; ``friction_present``) and a health record of a sampling period already stored
(``health_sampled_out``). Only rows stored now update
``joints`` (a joint's newest symptom), ``faults`` (a fault's newest alarm record, only ever from the
robot and joint the fault belongs to) and ``agents`` (when
each robot was last heard, its newest health record); each of those upserts keeps the newer of the two
by the record's time, then cycle, so the order in which records arrive (live, from the publishers'
caches, from a JSONL import, from two historians at once) never matters. Per-cycle rows of a day that
retention has already thinned are not stored (``expired``): they would come back as loose rows beside
that day's summary.
"""

from __future__ import annotations

import time
from collections import Counter
from dataclasses import dataclass, field

from edge_monitor.historian.database import Connection
from edge_monitor.historian.identity import THINNED_KINDS, Row
from edge_monitor.sinks.keys import ALARM, FRICTION, HEALTH, SYMPTOM

WATERMARK = "thinned_before_day"

_INSERT = ("INSERT INTO records (robot, joint, kind, ident, cycle, utc, at, day, received, stored, wear, state, "
           "fault, days_median, body) VALUES (?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?) "
           "ON CONFLICT (robot, kind, ident) DO NOTHING")
_NEWER = "(excluded.at > {t}.at OR (excluded.at = {t}.at AND COALESCE(excluded.cycle, -1) >= COALESCE({t}.cycle, -1)))"
_JOINT = ("INSERT INTO joints (robot, joint, cycle, at, utc, wear, days_median, alarm, body) "
          "VALUES (?, ?, ?, ?, ?, ?, ?, ?, ?) ON CONFLICT (robot, joint) DO UPDATE SET cycle = excluded.cycle, "
          "at = excluded.at, utc = excluded.utc, wear = excluded.wear, days_median = excluded.days_median, "
          "alarm = excluded.alarm, body = excluded.body WHERE " + _NEWER.format(t="joints"))
_FAULT = ("INSERT INTO faults (fault, robot, joint, quantity, state, is_open, cycle, at, body) "
          "VALUES (?, ?, ?, ?, ?, ?, ?, ?, ?) ON CONFLICT (fault) DO UPDATE SET state = excluded.state, "
          "is_open = excluded.is_open, cycle = excluded.cycle, at = excluded.at, body = excluded.body WHERE "
          "faults.robot = excluded.robot AND faults.joint = excluded.joint AND " + _NEWER.format(t="faults"))
_AGENT = ("INSERT INTO agents (robot, first_heard, last_heard) VALUES (?, ?, ?) ON CONFLICT (robot) DO UPDATE SET "
          "first_heard = CASE WHEN excluded.first_heard < agents.first_heard THEN excluded.first_heard "
          "ELSE agents.first_heard END, last_heard = CASE WHEN excluded.last_heard > agents.last_heard "
          "THEN excluded.last_heard ELSE agents.last_heard END")
_HEALTH = "UPDATE agents SET health_at = ?, health = ? WHERE robot = ? AND (health_at IS NULL OR health_at <= ?)"


@dataclass
class WriteResult:
    """What one batch did: rows ``stored``, ``duplicates``, ``friction_present``, ``health_sampled_out``,
    ``expired``; ``stored_rows``
    the rows stored (for latency and gap bookkeeping); ``stored_at`` the commit's clock [Unix s]."""

    stored: int = 0
    duplicates: int = 0
    friction_present: int = 0
    health_sampled_out: int = 0
    expired: int = 0
    by_kind: Counter = field(default_factory=Counter)
    stored_rows: list[Row] = field(default_factory=list)
    stored_at: float = 0.0


def watermark(conn: Connection) -> int:
    """The first day whose per-cycle rows are not thinned yet (0: none thinned)."""
    found = conn.rows("SELECT value FROM meta WHERE name = ?", (WATERMARK,))
    return int(found[0][0]) if found else 0


def insert_rows(conn: Connection, rows: list[Row], clock=time.time) -> WriteResult:
    """Store ``rows`` in one transaction (all or nothing); raises DatabaseUnavailable / RecordRefused."""
    result = WriteResult()
    stored_at = clock()
    rows, sampled_out = _one_health_per_period(rows)
    result.health_sampled_out += sampled_out
    with conn.transaction():
        first_open_day = watermark(conn)
        # one order for every writer (two historians on one PostgreSQL): rows, and the joints and faults
        # they update, are locked in the same sequence, so concurrent batches never deadlock
        for row in sorted(rows, key=_lock_order):
            if row.kind in THINNED_KINDS and row.day < first_open_day:
                result.expired += 1
                continue
            if conn.run(_INSERT, (row.robot, row.joint, row.kind, row.ident, row.cycle, row.utc, row.at, row.day,
                                  row.received, stored_at, row.wear, row.state, row.fault, row.days_median,
                                  row.body)) == 1:
                result.stored_rows.append(row)
                result.by_kind[row.kind] += 1
                _derived_tables(conn, row)
            elif row.kind == FRICTION:
                result.friction_present += 1
            elif row.kind == HEALTH:
                result.health_sampled_out += 1
            else:
                result.duplicates += 1
        _heard(conn, rows)
        newest: dict[str, Row] = {}
        for row in rows:
            if row.kind == HEALTH and (row.robot not in newest or row.at >= newest[row.robot].at):
                newest[row.robot] = row
        for robot, row in sorted(newest.items()):      # the newest health of every robot, also one sampled out
            conn.run(_HEALTH, (row.at, row.body, robot, row.at))
    result.stored = len(result.stored_rows)
    result.stored_at = stored_at
    return result


def _one_health_per_period(rows: list[Row]) -> tuple[list[Row], int]:
    """``rows`` with, of the health records of one robot and sampling period, only the first and the
    robot's newest (health comes every few seconds: one round trip each would dominate the batch)."""
    newest = {row.robot: row for row in rows if row.kind == HEALTH}
    seen: set[tuple[str, str]] = set()
    kept = []
    for row in rows:
        if row.kind == HEALTH and (row.robot, row.ident) in seen and newest[row.robot] is not row:
            continue
        seen.add((row.robot, row.ident))
        kept.append(row)
    return kept, len(rows) - len(kept)


def _lock_order(row: Row) -> tuple[str, int, str, str]:
    return row.robot, -1 if row.joint is None else row.joint, row.kind, row.ident


def _derived_tables(conn: Connection, row: Row) -> None:
    if row.kind == SYMPTOM:
        conn.run(_JOINT, (row.robot, row.joint, row.cycle, row.at, row.utc, row.wear, row.days_median,
                          int(row.record.get("alarm") is True), row.body))
    elif row.kind == ALARM:
        open_flag = row.record.get("open")
        is_open = int(open_flag) if isinstance(open_flag, bool) else int(row.state not in ("cleared", "acknowledged"))
        conn.run(_FAULT, (row.fault, row.robot, row.joint, str(row.record.get("quantity"))[:200], row.state, is_open,
                          row.cycle, row.at, row.body))


def _heard(conn: Connection, rows: list[Row]) -> None:
    """``agents``: first and last time each robot of the batch was heard (live rows only, not imports)."""
    span: dict[str, tuple[float, float]] = {}
    for row in rows:
        if row.heard:
            low, high = span.get(row.robot, (row.received, row.received))
            span[row.robot] = (min(low, row.received), max(high, row.received))
    for robot, (low, high) in sorted(span.items()):
        conn.run(_AGENT, (robot, low, high))
