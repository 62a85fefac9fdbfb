"""A history question, validated once: which records (robot, joint, kinds, time range), how many, from
where on. The same object comes from the command line (``edge-monitor history``) and from a Zenoh
selector (``edge/history/records?robot=r1;kind=symptom;since=7d``), so both get the same checks and the
same one-line messages. Every answer is bounded: at most :data:`MAX_LIMIT` records a page, with a
cursor to the next page.
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass
from typing import Any, Mapping

from edge_monitor.historian.identity import STORED_KINDS
from edge_monitor.historian.times import TimeFormatError, parse_age, parse_time, utc_of_seconds
from edge_monitor.sinks.keys import RESERVED_ROBOTS, check_robot_name

DEFAULT_LIMIT = 100
MAX_LIMIT = 1000
MAX_FLEET_LIMIT = 10_000
DAILY = "daily"
#: What can be asked (the last segment of ``edge/history/<what>``).
ANSWERS = ("records", "alarms", "fleet", "gaps", "daily", "status")
RANKS = ("wear", "forecast", "robot")
PARAMETERS = ("robot", "joint", "kind", "since", "until", "limit", "cursor", "rank", "stale")
#: Largest record id a cursor may name (the databases' 64-bit signed integer).
MAX_RECORD_ID = 2 ** 63 - 1
_CURSOR = re.compile(r"^(?P<at>-?\d+(?:\.\d+)?(?:e[+-]?\d+)?):(?P<id>\d{1,19})$")


class QueryError(ValueError):
    """A question that cannot be answered as asked (says which parameter and what it accepts)."""


@dataclass(frozen=True)
class Cursor:
    """Where the next page starts: after the record at (``at``, ``id``) in (time, id) order."""

    at: float
    id: int

    def text(self) -> str:
        return f"{self.at!r}:{self.id}"

    @classmethod
    def parse(cls, text: str) -> "Cursor":
        match = _CURSOR.match(str(text).strip())
        if not match or not math.isfinite(float(match["at"])) or int(match["id"]) > MAX_RECORD_ID:
            raise QueryError(f"cursor {str(text)[:40]!r} is not one this historian gave (TIME:ID)")
        return cls(float(match["at"]), int(match["id"]))


@dataclass(frozen=True)
class HistoryQuery:
    """``what``: records | alarms (the open ones) | fleet | gaps | daily | status. Times are Unix seconds."""

    what: str = "records"
    robot: str | None = None
    joint: int | None = None
    kinds: tuple[str, ...] = ()
    since: float | None = None
    until: float | None = None
    limit: int = DEFAULT_LIMIT
    cursor: Cursor | None = None
    rank: str = "wear"
    stale_s: float = 3600.0

    def __post_init__(self) -> None:
        if self.what not in ANSWERS:
            raise QueryError(f"unknown question {self.what!r}: ask edge/history/<{'|'.join(ANSWERS)}>")
        if self.robot is not None:
            try:
                check_robot_name(self.robot)
            except ValueError:
                what = ("a reserved name, no robot has it" if self.robot in RESERVED_ROBOTS
                        else "1 … 64 letters, digits, '_', '-' or '.'")
                raise QueryError(f"robot {self.robot[:80]!r}: {what}") from None
        if self.joint is not None and not (isinstance(self.joint, int) and 0 <= self.joint <= 999):
            raise QueryError(f"joint {self.joint!r}: a joint number is 0 … 999")
        unknown = [k for k in self.kinds if k not in STORED_KINDS]
        if unknown:
            raise QueryError(f"kind {unknown[0][:40]!r}: one of {', '.join(STORED_KINDS)} (daily summaries: "
                             "edge/history/daily, history --daily)")
        top = MAX_FLEET_LIMIT if self.what == "fleet" else MAX_LIMIT
        if not (isinstance(self.limit, int) and 1 <= self.limit <= top):
            raise QueryError(f"limit {self.limit!r}: 1 … {top} a page (page on with the cursor of the answer)")
        if self.since is not None and self.until is not None and self.since > self.until:
            raise QueryError("since is after until: swap them")
        if self.rank not in RANKS:
            raise QueryError(f"rank {self.rank!r}: one of {', '.join(RANKS)}")
        if not (math.isfinite(self.stale_s) and 1 <= self.stale_s <= 3.2e7):
            raise QueryError(f"stale {self.stale_s!r}: 1 s … one year")

    def describe(self) -> dict[str, Any]:
        """The question as it was understood (echoed in every answer)."""
        out: dict[str, Any] = {"what": self.what, "robot": self.robot, "joint": self.joint,
                               "kinds": list(self.kinds), "since": utc_of_seconds(self.since),
                               "until": utc_of_seconds(self.until), "limit": self.limit,
                               "cursor": None if self.cursor is None else self.cursor.text()}
        if self.what == "fleet":
            out.update(rank=self.rank, stale_s=self.stale_s)
        return out


def _int_param(name: str, text: str) -> int:
    if not re.fullmatch(r"\d{1,9}", text.strip()):
        raise QueryError(f"{name}={text[:40]!r}: a whole number")
    return int(text)


def query_of(what: str, parameters: Mapping[str, str], now: float | None = None) -> HistoryQuery:
    """The question a selector asks: ``what`` (the key's last segment) and its parameters (strings)."""
    unknown = sorted(set(parameters) - set(PARAMETERS))
    if unknown:
        raise QueryError(f"unknown parameter {unknown[0][:40]!r}: use {', '.join(PARAMETERS)}")
    args: dict[str, Any] = {"what": what}
    try:
        if parameters.get("robot"):
            args["robot"] = parameters["robot"]
        if parameters.get("joint"):
            args["joint"] = _int_param("joint", parameters["joint"])
        if parameters.get("kind"):
            args["kinds"] = tuple(k for k in parameters["kind"].replace("|", ",").split(",") if k)
        for name in ("since", "until"):
            if parameters.get(name):
                args[name] = parse_time(parameters[name], now)
        if parameters.get("limit"):
            args["limit"] = _int_param("limit", parameters["limit"])
        if parameters.get("cursor"):
            args["cursor"] = Cursor.parse(parameters["cursor"])
        if parameters.get("rank"):
            args["rank"] = parameters["rank"]
        if parameters.get("stale"):
            args["stale_s"] = parse_age(parameters["stale"])
    except TimeFormatError as exc:
        raise QueryError(str(exc)) from None
    return HistoryQuery(**args)


def parameters_of(query: HistoryQuery) -> dict[str, str]:
    """The selector parameters that ask ``query`` (the inverse of :func:`query_of`)."""
    out: dict[str, str] = {}
    if query.robot is not None:
        out["robot"] = query.robot
    if query.joint is not None:
        out["joint"] = str(query.joint)
    if query.kinds:
        out["kind"] = ",".join(query.kinds)
    for name in ("since", "until"):
        value = getattr(query, name)
        if value is not None:
            out[name] = str(utc_of_seconds(value))
    out["limit"] = str(query.limit)
    if query.cursor is not None:
        out["cursor"] = query.cursor.text()
    if query.what == "fleet":
        out.update(rank=query.rank, stale=f"{query.stale_s:g}s")
    return out
