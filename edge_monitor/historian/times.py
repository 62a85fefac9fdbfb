"""Times the historian reads and writes: ISO 8601 UTC text ⇄ Unix seconds, and the ``--since``/``until``
forms a person types (``2026-11-26``, ``2026-11-26T13:00Z``, ``-7d``, ``24h``, ``now``)."""

from __future__ import annotations

import math
import re
import time
from datetime import datetime, timezone

from edge_monitor.records import utc_text

#: Seconds of a day; records are thinned by whole UTC days (day = floor(at / DAY_S)).
DAY_S = 86400.0
#: Earliest and latest instants a query may name (years 1970 … 9999): wider is refused, not clamped.
EARLIEST_S, LATEST_S = 0.0, 253402300799.0
_RELATIVE = re.compile(r"^-?(?P<n>\d+(?:\.\d+)?)\s*(?P<unit>s|m|h|d|w)$")
_UNIT_S = {"s": 1.0, "m": 60.0, "h": 3600.0, "d": DAY_S, "w": 7 * DAY_S}


class TimeFormatError(ValueError):
    """A time a user or a peer gave that is not one of the accepted forms."""


def seconds_of_utc(text: object) -> float | None:
    """Unix seconds of an ISO 8601 time (``2026-11-26T13:31:05.412Z``; no zone means UTC), None when
    ``text`` is not such a string (a record's ``utc`` may be null or, from a hostile peer, anything)."""
    if not isinstance(text, str) or not 10 <= len(text) <= 40:
        return None
    try:
        moment = datetime.fromisoformat(text)
    except ValueError:
        return None
    if moment.tzinfo is None:
        moment = moment.replace(tzinfo=timezone.utc)
    seconds = moment.timestamp()
    return seconds if math.isfinite(seconds) else None


def parse_time(text: str, now: float | None = None) -> float:
    """Unix seconds of a time a person typed: ISO 8601 (date, or date and time; UTC unless a zone is
    given), ``now``, or an age before now (``30m``, ``24h``, ``7d``, ``2w``, with or without a leading
    ``-``). :class:`TimeFormatError` saying the accepted forms for anything else."""
    now = time.time() if now is None else now
    value = str(text).strip()
    if value == "now":
        return now
    relative = _RELATIVE.match(value)
    if relative:
        seconds = now - float(relative["n"]) * _UNIT_S[relative["unit"]]
    else:
        parsed = seconds_of_utc(value)
        if parsed is None:
            raise TimeFormatError(f"time {value[:40]!r} is not ISO 8601 (2026-11-26 or 2026-11-26T13:00Z), 'now', "
                                  "or an age such as 30m, 24h, 7d, 2w")
        seconds = parsed
    if not EARLIEST_S <= seconds <= LATEST_S:
        raise TimeFormatError(f"time {value[:40]!r} is outside 1970 … 9999")
    return seconds


def parse_age(text: str) -> float:
    """Seconds of an age a person typed: ``90`` (seconds), ``30m``, ``1h``, ``2d``, ``1w``."""
    value = str(text).strip()
    if value.replace(".", "", 1).isdigit():
        value += "s"
    match = _RELATIVE.match(value.lstrip("-"))
    if not match:
        raise TimeFormatError(f"age {value[:40]!r} is not a number of seconds or 30m, 1h, 2d, 1w")
    return float(match["n"]) * _UNIT_S[match["unit"]]


def utc_of_seconds(seconds: float | None) -> str | None:
    """ISO 8601 UTC text of Unix seconds, to the millisecond (any finite time, also before 2000)."""
    if seconds is None or not math.isfinite(seconds) or not EARLIEST_S <= seconds <= LATEST_S:
        return None
    if seconds >= 946684800.0:
        return utc_text(seconds)
    text = datetime.fromtimestamp(seconds, tz=timezone.utc).isoformat(timespec="milliseconds")
    return text.replace("+00:00", "Z")


def day_of(seconds: float) -> int:
    """The UTC day number of Unix seconds (days since 1970-01-01)."""
    return int(math.floor(seconds / DAY_S))
