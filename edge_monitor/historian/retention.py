"""Retention: per-cycle records kept for a set time, then thinned by whole UTC days; alarms, advisories
and maintenance requests kept for ever.

Thinning a day, in one transaction: its symptoms become one ``daily`` row per joint (records, first and
last cycle, wear min/max/mean, alarm records), then of every (robot, joint, kind) only the day's last
symptom, friction and health record stays (so a curve or a full record per day remains), and the
watermark moves past the day. A record of a thinned day that arrives later (an old JSONL file) is not
stored (``expired``), so a day is summarised once and never comes back as loose rows.
"""

from __future__ import annotations

import logging
import math
import time
from dataclasses import dataclass

from edge_monitor.historian.database import Connection
from edge_monitor.historian.identity import THINNED_KINDS
from edge_monitor.historian.times import DAY_S, day_of, utc_of_seconds
from edge_monitor.historian.writes import WATERMARK, watermark

log = logging.getLogger(__name__)

_SUMMARY = """INSERT INTO daily (robot, joint, day, records, first_cycle, last_cycle, wear_min, wear_max, wear_sum,
                                 wear_n, alarm_records)
    SELECT robot, joint, day, COUNT(*), MIN(cycle), MAX(cycle), MIN(wear), MAX(wear), SUM(wear), COUNT(wear),
           SUM(CASE WHEN body LIKE '%"alarm":true%' THEN 1 ELSE 0 END)
    FROM records WHERE kind = 'symptom' AND day = ? GROUP BY robot, joint, day
    ON CONFLICT (robot, joint, day) DO NOTHING"""
_THIN = """DELETE FROM records WHERE day = ? AND kind IN ({kinds}) AND id NOT IN (
    SELECT id FROM (SELECT id, ROW_NUMBER() OVER (PARTITION BY robot, joint, kind ORDER BY at DESC, id DESC) AS rn
                    FROM records WHERE day = ? AND kind IN ({kinds})) AS ranked WHERE rn = 1)"""


@dataclass(frozen=True)
class Retention:
    """Per-cycle records are kept ``keep_days`` whole days (then thinned); 0 keeps them for ever."""

    keep_days: float = 180.0

    def __post_init__(self) -> None:
        if not (isinstance(self.keep_days, (int, float)) and math.isfinite(self.keep_days)
                and 0 <= self.keep_days <= 36500):
            raise ValueError(f"retention {self.keep_days!r} days must be 0 (for ever) … 36500; fix --keep-days")

    def first_kept_day(self, now: float) -> int | None:
        """The first day not to thin at ``now`` (None: keep everything)."""
        return None if not self.keep_days else day_of(now - self.keep_days * DAY_S)


@dataclass
class ThinResult:
    days: int = 0
    removed: int = 0
    summaries: int = 0
    watermark: int = 0


def thin(conn: Connection, retention: Retention, now: float | None = None, max_days: int = 366) -> ThinResult:
    """Thin every day before the retention horizon not thinned yet (at most ``max_days`` per call, one
    transaction per day: a long backlog does not hold the database for long)."""
    result = ThinResult()
    horizon = retention.first_kept_day(time.time() if now is None else now)
    if horizon is None:
        return result
    kinds = ", ".join(f"'{k}'" for k in THINNED_KINDS)
    with conn.transaction(write=False):
        start = watermark(conn)
        oldest = conn.rows("SELECT MIN(day) FROM records WHERE kind IN (" + kinds + ")")[0][0]
    day = max(start, int(oldest) if oldest is not None else horizon)
    while day < horizon and result.days < max_days:
        with conn.transaction():
            if watermark(conn) > day:        # another historian thinned it meanwhile
                day += 1
                continue
            result.summaries += conn.run(_SUMMARY, (day,))
            result.removed += conn.run(_THIN.format(kinds=kinds), (day, day))
            conn.run("INSERT INTO meta (name, value) VALUES (?, ?) ON CONFLICT (name) DO UPDATE SET value = "
                     "excluded.value", (WATERMARK, str(day + 1)))
        result.days += 1
        day += 1
    result.watermark = max(day, start)
    if result.days:
        log.info("retention: %d day(s) thinned up to %s: %d records removed, %d daily summaries", result.days,
                 str(utc_of_seconds(result.watermark * DAY_S))[:10], result.removed, result.summaries)
    return result
