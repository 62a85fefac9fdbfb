"""What a stored record is: its kind, its identity (the exactly-once key) and its indexed columns.

A record is stored at most once per identity (``UNIQUE (robot, kind, ident)``), so a redelivery, a
replayed JSONL file or a second historian on the same database never adds a row. The identity is what
tells two real records apart and nothing else:

* symptom, friction: ``<joint>/<cycle>/<stamp>``; ``stamp`` is the cycle's wall time ``utc`` (from the
  frames) or, for a stream without wall time, ``t=<controller time>`` (a friction record carries no
  ``t``: ``t=?``): a controller that restarts its cycle numbers makes new records (new stamps), an
  agent that publishes a cycle again makes the same.
* alarm: ``<joint>/<cycle>/<state>/<fault>/<utc>``; ``fault`` is the record's fault id, or for a record
  written before faults existed ``<quantity>`` (such a record is a fault of its own, docs/OUTPUTS.md).
* advisory: ``<joint>/<cycle>/<advisory>/<covariate>/<state>/<utc>``.
* health: ``<bucket>``, the record's time divided by the sampling period (``HealthSampling``): health is
  telemetry sent every few seconds; one record per robot and period is kept, the newest of every robot
  always in the ``agents`` table.
* maintenance (a request put on ``edge/<robot>/<joint>/maintenance``, seen by the historian):
  ``<joint>/<zenoh timestamp or arrival ms>/<digest of the payload>``.

Anything that cannot be one of these (a field its schema requires missing or of the wrong type, a ``utc``
that is not ISO 8601 UTC or is more than a day ahead of its arrival (:mod:`.record_checks`), a robot or
joint that disagrees with its key, an alarm whose fault id is not one of that key's joint
(``<robot>/<joint>/…``), no cycle) is a :class:`Rejection` with a reason the historian counts; nothing
raises.
"""

from __future__ import annotations

import hashlib
import json
import math
from dataclasses import dataclass, field
from typing import Any

from edge_monitor.historian.record_checks import field_problem, utc_problem
from edge_monitor.historian.times import day_of, seconds_of_utc, utc_of_seconds
from edge_monitor.records import to_json
from edge_monitor.sinks.keys import ADVISORY, ALARM, FRICTION, HEALTH, MAINTENANCE, SYMPTOM, check_robot_name
from protocol.numbers import finite_or_none

#: Kinds kept per cycle (or per sampling period) and thinned after the retention time.
THINNED_KINDS = (SYMPTOM, FRICTION, HEALTH)
#: Kinds kept for ever: what a person was told or did.
KEPT_KINDS = (ALARM, ADVISORY, MAINTENANCE)
STORED_KINDS = THINNED_KINDS + KEPT_KINDS
#: Largest record accepted [bytes of JSON] (a symptom record is a few kB).
MAX_RECORD_BYTES = 1 << 20
_TEXT_CAP = 200                      # longest fault id / state / quantity kept in an indexed column


@dataclass(frozen=True)
class HealthSampling:
    """One health record per robot and ``every_s`` seconds is stored (the first of each period)."""

    every_s: float = 600.0

    def __post_init__(self) -> None:
        if not (isinstance(self.every_s, (int, float)) and math.isfinite(self.every_s) and 1 <= self.every_s <= 86400):
            raise ValueError(f"health sampling period {self.every_s!r} must be 1 … 86400 s; fix --health-every")


@dataclass(frozen=True)
class Row:
    """One record as the database stores it (``body`` the record's strict JSON text)."""

    kind: str
    robot: str
    joint: int | None
    ident: str
    cycle: int | None
    utc: str | None
    at: float                        # the record's time: its utc, else when it arrived [Unix s]
    received: float                  # when the historian got it [Unix s]
    body: str
    record: dict[str, Any] = field(repr=False, compare=False)
    wear: float | None = None
    state: str | None = None
    fault: str | None = None
    days_median: float | None = None
    derived: bool = False            # made from another record (a symptom's friction curve)
    heard: bool = True               # received from the agent now (False: imported from a file)

    @property
    def day(self) -> int:
        return day_of(self.at)


@dataclass(frozen=True)
class Rejection:
    """A record that cannot be stored, and why (a counter name: ``rejected_<reason>``)."""

    reason: str
    detail: str = ""


def _int(value: Any) -> int | None:
    return value if isinstance(value, int) and not isinstance(value, bool) and 0 <= value < 2 ** 53 else None


def _text(value: Any) -> str | None:
    return value[:_TEXT_CAP].replace("\x00", "") if isinstance(value, str) else None


def _nested(record: dict[str, Any], *path: str) -> Any:
    value: Any = record
    for name in path:
        value = value.get(name) if isinstance(value, dict) else None
    return value


def forecast_days(record: dict[str, Any]) -> float | None:
    """The prognosis' median days to the critical wear (``prognosis.days.median``), None when absent."""
    return finite_or_none(_nested(record, "prognosis", "days", "median"))


def row_of(kind: str, robot: str, joint: int | None, record: Any, received: float,
           sampling: HealthSampling = HealthSampling(), heard: bool = True) -> Row | Rejection:
    """The row of a record received under ``edge/<robot>/<joint>/<kind>`` (``joint`` None for the
    agent's keys), or why it cannot be stored."""
    if kind not in STORED_KINDS:
        return Rejection("kind", kind[:40])
    if not isinstance(record, dict):
        return Rejection("not_an_object")
    try:
        check_robot_name(robot)
    except ValueError:
        return Rejection("robot", str(robot)[:80])
    if record.get("robot", robot) != robot:
        return Rejection("robot_mismatch", f"key {robot}, record {str(record.get('robot'))[:80]}")
    if kind != HEALTH:
        record_joint = _int(record.get("joint", joint))
        if joint is None or record_joint != joint:
            return Rejection("joint_mismatch", f"key {joint}, record {str(record.get('joint'))[:20]}")
    if kind == ALARM and not _fault_of_key(robot, joint, record.get("fault")):
        return Rejection("fault_mismatch", f"key {robot}/{joint}, fault {str(record.get('fault'))[:80]}")
    body = to_json(record)
    if len(body) > MAX_RECORD_BYTES:
        return Rejection("too_large", f"{len(body)} bytes")
    utc = record.get("utc") if isinstance(record.get("utc"), str) else None
    at = seconds_of_utc(utc)
    if at is None:
        utc, at = None, received
    cycle = _int(record.get("cycle"))
    if kind in (SYMPTOM, FRICTION, ALARM, ADVISORY) and cycle is None:
        return Rejection("cycle", str(record.get("cycle"))[:20])
    problem = utc_problem(record.get("utc"), received) or field_problem(kind, record)
    if problem is not None:
        return Rejection(*problem)
    ident = _identity(kind, joint, cycle, record, utc, at, sampling)
    return Row(kind, robot, None if kind == HEALTH else joint, ident, cycle, utc, at, received, body, record,
               wear=finite_or_none(_nested(record, "wear", "estimate")) if kind == SYMPTOM else None,
               state=_text(record.get("state")), fault=_fault(kind, robot, joint, cycle, record),
               days_median=forecast_days(record) if kind == SYMPTOM else None, heard=heard)


def _identity(kind: str, joint: int | None, cycle: int | None, record: dict[str, Any], utc: str | None,
              at: float, sampling: HealthSampling) -> str:
    if kind in (SYMPTOM, FRICTION):
        t = finite_or_none(record.get("t"))
        stamp = utc if utc is not None else ("t=" + repr(t) if t is not None else "t=?")
        return f"{joint}/{cycle}/{stamp}"
    if kind == ALARM:
        fault = _text(record.get("fault")) or _text(record.get("quantity")) or "?"
        return f"{joint}/{cycle}/{_text(record.get('state'))}/{fault}/{utc}"
    if kind == ADVISORY:
        return (f"{joint}/{cycle}/{_text(record.get('advisory'))}/{_text(record.get('covariate'))}/"
                f"{_text(record.get('state'))}/{utc}")
    if kind == HEALTH:
        return str(int(at // sampling.every_s))
    digest = hashlib.sha256(json.dumps(record.get("request"), sort_keys=True).encode()).hexdigest()[:16]
    return f"{joint}/{record.get('stamp') or utc}/{digest}"


def _fault_of_key(robot: str, joint: int | None, fault: Any) -> bool:
    """Whether an alarm's ``fault`` id may come on ``edge/<robot>/<joint>/alarm``: none (a record written
    before faults existed) or one of that joint, ``<robot>/<joint>/…`` (a fault belongs to its joint; another
    robot's record must never close or change it)."""
    return fault is None or (isinstance(fault, str) and fault.startswith(f"{robot}/{joint}/")
                             and len(fault) <= _TEXT_CAP and "\x00" not in fault)


def _fault(kind: str, robot: str, joint: int | None, cycle: int | None, record: dict[str, Any]) -> str | None:
    """The fault an alarm record belongs to (legacy records: a fault of their own)."""
    if kind != ALARM:
        return None
    return _text(record.get("fault")) or f"{robot}/{joint}/{cycle}/{_text(record.get('quantity')) or '?'}"


def friction_of(row: Row) -> Row | None:
    """The friction record a symptom carries (``Symptom.friction_record()``), as its own row: a friction
    sample Zenoh dropped (it is published DROP) or a JSONL import still stores every curve once."""
    friction = row.record.get("friction")
    if row.kind != SYMPTOM or not isinstance(friction, dict):
        return None
    record = {"schema": row.record.get("schema", 1), "robot": row.robot, "joint": row.joint, "cycle": row.cycle,
              "utc": row.record.get("utc"), **friction}
    made = row_of(FRICTION, row.robot, row.joint, record, row.received, heard=row.heard)
    if isinstance(made, Rejection):
        return None
    return Row(**{**made.__dict__, "derived": True})


def maintenance_record(robot: str, joint: int, payload: bytes, attachment: bytes | None, stamp: str | None,
                       received: float) -> dict[str, Any]:
    """The stored form of a maintenance request put on Zenoh: its text (cut to 500 characters, invalid
    UTF-8 replaced), attachment, the Zenoh timestamp (``stamp``) and when it was seen."""
    def text(data: bytes | None, cap: int) -> str | None:
        return None if data is None else data[:cap * 4].decode("utf-8", "replace")[:cap]

    return {"schema": 1, "robot": robot, "joint": joint, "utc": utc_of_seconds(received),
            "request": text(payload, 500), "attachment": text(attachment, 200), "stamp": stamp,
            "source": "request"}
