"""Typed records the agent publishes (symptom, decision, alarm, health) and their strict JSON form.

Every record has ``to_dict()`` giving the published layout (docs/OUTPUTS.md) and is serialised with
:func:`to_json`: NaN and ±inf become ``null`` (JSON has no NaN), numpy scalars and arrays become Python
values. The same serialiser writes the state file, JSONL lines, Zenoh payloads and CLI output.
"""

from __future__ import annotations

import json
import math
import time
from dataclasses import dataclass, field
from datetime import datetime, timezone
from typing import Any

import numpy as np

from protocol.numbers import finite_or_none, is_count, is_finite_number  # noqa: F401 (part of this module's interface)

#: Version of every published record (symptom, alarm, friction, health): the "schema" field. Fields are
#: only ever added within a version (``utc`` was), so a reader of version 1 ignores what it does not know.
SCHEMA_VERSION = 1

#: Frame timestamps before 2000-01-01T00:00:00Z are not wall-clock time (a log with relative time, a
#: simulated clock starting at 0): records then carry ``"utc": null``.
EARLIEST_WALL_TIME = 946684800.0
#: Frame timestamps from 10000-01-01T00:00:00Z on cannot be written as ISO 8601 (nor by Python's datetime): a
#: log whose clock jumped there (a corrupted or hostile timestamp) gives ``"utc": null`` too.
LATEST_WALL_TIME = 253402300800.0


def utc_text(timestamp: float | None) -> str | None:
    """ISO 8601 UTC text of a Unix timestamp [s], to the millisecond (``2026-11-26T13:09:00.250Z``);
    None when ``timestamp`` is missing, not finite, before :data:`EARLIEST_WALL_TIME` or from
    :data:`LATEST_WALL_TIME` on."""
    if timestamp is None or not math.isfinite(timestamp) or not EARLIEST_WALL_TIME <= timestamp < LATEST_WALL_TIME:
        return None
    text = datetime.fromtimestamp(timestamp, tz=timezone.utc).isoformat(timespec="milliseconds")
    return text.replace("+00:00", "Z")


def utc_now() -> str | None:
    """The host clock as :func:`utc_text`."""
    return utc_text(time.time())


def to_strict(value: Any) -> Any:
    """``value`` with NaN/±inf → None and numpy scalars/arrays → Python types, recursively."""
    if isinstance(value, dict):
        return {str(k): to_strict(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [to_strict(v) for v in value]
    if isinstance(value, np.ndarray):
        return to_strict(value.tolist())
    if isinstance(value, (bool, np.bool_)):
        return bool(value)
    if isinstance(value, (int, np.integer)):
        return int(value)
    if isinstance(value, (float, np.floating)):
        number = float(value)
        return number if math.isfinite(number) else None
    if hasattr(value, "to_dict"):
        return to_strict(value.to_dict())
    return value


def to_json(value: Any, **kwargs: Any) -> str:
    """Compact strict JSON text of ``value`` (``kwargs`` go to ``json.dumps``, e.g. ``indent``)."""
    kwargs.setdefault("separators", (",", ":"))
    return json.dumps(to_strict(value), allow_nan=False, **kwargs)


@dataclass(frozen=True)
class Decision:
    """One detector's answer for one cycle (the ``decisions[QUANTITY]`` record of a symptom).

    ``statistic`` and ``threshold`` are the GLR log-likelihood ratio and its alarm level (natural log,
    dimensionless); ``delta`` is the estimated shift in the quantity's own units; ``miss_probability``
    is Pm at the current estimate. ``reason`` says why a field is missing (learning, skipped value).
    ``calibration`` describes how the threshold was set (published only when present).
    """

    state: str                               # "learning" | "monitoring"
    statistic: float | None = None
    threshold: float | None = None
    alarm: bool = False
    change_cycle: int | None = None
    delta: tuple[float, ...] | None = None
    miss_probability: float | None = None
    reason: str = ""
    calibration: dict[str, Any] | None = None

    def to_dict(self) -> dict[str, Any]:
        out: dict[str, Any] = {
            "state": self.state, "statistic": finite_or_none(self.statistic),
            "threshold": finite_or_none(self.threshold), "alarm": bool(self.alarm),
            "change_cycle": self.change_cycle,
            "delta": None if self.delta is None else [finite_or_none(v) for v in self.delta],
            "miss_probability": finite_or_none(self.miss_probability)}
        if self.reason:
            out["reason"] = self.reason
        if self.calibration is not None:
            out["calibration"] = self.calibration
        return out


#: States of a published alarm record (one fault of one joint; :mod:`edge_monitor.pipeline.fault_grouping`).
ALARM_STATES = ("raised", "updated", "chattering", "acknowledged", "cleared")


@dataclass(frozen=True)
class Alarm:
    """An alarm event. A detector's own crossing (what :class:`~edge_monitor.pipeline.detectors.DetectorBank`
    reports) has ``fault`` None; a published record is about one fault of one joint
    (:mod:`edge_monitor.pipeline.fault_grouping`): "raised" (its first crossing), "updated" (more detectors
    agree), "chattering" (a crossing soon after an acknowledgement), "acknowledged" (judged false by an
    operator: the statistics restart on the same nominal and threshold; ``by``/``note`` say who and why)
    or "cleared" (a declared maintenance: the detectors relearn). ``quantity`` is the detector that raised
    the fault; ``detectors`` the evidence of every detector the record names; ``open`` whether the fault
    is still open after it."""

    robot: str
    joint: int
    cycle: int
    quantity: str
    state: str                                # one of ALARM_STATES
    statistic: float | None = None
    threshold: float | None = None
    miss_probability: float | None = None
    change_cycle: int | None = None
    by: str | None = None
    note: str | None = None
    #: why, as far as the agent can tell: the shift estimate in the quantity's units (per input) and the
    #: operating conditions then against the learned ones (:mod:`edge_monitor.pipeline.operating_range`)
    cause: dict[str, Any] | None = None
    utc: str | None = None                    # wall time of the cycle's end (or of a maintenance), ISO 8601
    fault: str | None = None                  # "<robot>/<joint>/<cycle it was raised>"
    detectors: tuple[dict[str, Any], ...] | None = None
    open: bool | None = None
    prognosis: dict[str, Any] | None = None   # the joint's prognosis at this cycle (the symptom's section)

    def to_dict(self) -> dict[str, Any]:
        out: dict[str, Any] = {
            "schema": SCHEMA_VERSION, "robot": self.robot, "joint": self.joint, "cycle": self.cycle,
            "utc": self.utc,
            "quantity": self.quantity, "state": self.state, "statistic": finite_or_none(self.statistic),
            "threshold": finite_or_none(self.threshold),
            "miss_probability": finite_or_none(self.miss_probability), "change_cycle": self.change_cycle}
        out.update({k: v for k, v in (("by", self.by), ("note", self.note), ("cause", self.cause),
                                      ("fault", self.fault), ("open", self.open), ("prognosis", self.prognosis))
                    if v is not None})
        if self.detectors is not None:
            out["detectors"] = to_strict(list(self.detectors))
        return out

    def evidence(self) -> dict[str, Any]:
        """This detector crossing as one entry of a fault's ``detectors``: what crossed, when, by how much."""
        return {"quantity": self.quantity, "cycle": self.cycle, "statistic": finite_or_none(self.statistic),
                "threshold": finite_or_none(self.threshold), "miss_probability": finite_or_none(self.miss_probability),
                "change_cycle": self.change_cycle, "cause": self.cause}


@dataclass(frozen=True)
class Advisory:
    """Something a person should know that is not a fault: an operating condition that left the range the
    joint's detectors learned in (kind "operating_range", ``state`` "entered" the outside) or came back
    ("left"); or the prognosis's early warning (kind "prognosis": ``covariate`` names the probability of
    critical wear within the warning horizon, ``value`` is it, ``learned`` holds (warning level, horizon
    in days); "entered" when it reached the level, "left" when it fell below half of it; ``prognosis``
    the forecast then)."""

    robot: str
    joint: int
    cycle: int
    kind: str                                 # "operating_range" | "prognosis"
    state: str                                # "entered" | "left"
    covariate: str
    value: float
    learned: tuple[float, float]
    utc: str | None = None                    # wall time of the cycle's end, ISO 8601
    prognosis: dict[str, Any] | None = None

    def to_dict(self) -> dict[str, Any]:
        out = {"schema": SCHEMA_VERSION, "robot": self.robot, "joint": self.joint, "cycle": self.cycle,
               "utc": self.utc, "advisory": self.kind, "state": self.state, "covariate": self.covariate,
               "value": finite_or_none(self.value), "learned": [finite_or_none(v) for v in self.learned],
               "message": self.message()}
        if self.prognosis is not None:
            out["prognosis"] = self.prognosis
        return out

    def message(self) -> str:
        if self.kind == "prognosis":
            level, days = self.learned
            said, within = (self.prognosis or {}).get("text", ""), f"P(critical wear within {days:g} days)"
            if self.state == "entered":
                return f"{within} {self.value:.2f} ≥ {level:.2g}: plan the service ({said})"
            return f"{within} {self.value:.2f}, below {level / 2:.2g} for a while ({said})"
        where = "outside" if self.state == "entered" else "back inside"
        return (f"{self.covariate} {self.value:.3g} {where} the learned range "
                f"{self.learned[0]:.3g} … {self.learned[1]:.3g}: operating condition, not wear")


@dataclass
class Symptom:
    """What one joint reports for one cycle.

    ``sections`` holds one JSON-ready section per registered feature (``"wear"``, ``"kl"``, …), in
    registration order; ``decisions`` one :class:`Decision` per watched quantity. ``alarms`` are the
    alarm transitions of this cycle, ``advisories`` its advisories, and ``extras`` data for viewers that
    are not published (e.g. the cycle's torque density); none of them is part of :meth:`to_dict`.
    """

    robot: str
    joint: int
    cycle: int
    t: float                                  # controller time at the end of the cycle [s]
    friction: dict[str, list[float]]          # {"speeds", "torque", "stderr"}
    sections: dict[str, dict[str, Any]]
    decisions: dict[str, Decision]
    load: dict[str, float | None]             # the controller's load estimate {"mean", "std"}
    skipped: dict[str, int]
    critical_wear: float
    reasons: dict[str, str] = field(default_factory=dict)
    partial: bool = False
    alarms: list[Alarm] = field(default_factory=list)
    advisories: list[Advisory] = field(default_factory=list)
    extras: dict[str, Any] = field(default_factory=dict)
    utc: str | None = None                    # wall time of the cycle's end from the frame timestamps, ISO 8601

    @property
    def alarm(self) -> bool:
        """Whether any detector of this joint is in alarm (latched)."""
        return any(d.alarm for d in self.decisions.values())

    def to_dict(self) -> dict[str, Any]:
        out: dict[str, Any] = {"schema": SCHEMA_VERSION, "robot": self.robot, "joint": self.joint,
                               "cycle": self.cycle, "t": self.t, "utc": self.utc, "friction": self.friction}
        out.update(self.sections)
        out.update({"decisions": {q: d.to_dict() for q, d in self.decisions.items()}, "alarm": self.alarm,
                    "load": self.load, "skipped": self.skipped, "critical_wear": self.critical_wear})
        if self.reasons:
            out["reasons"] = self.reasons
        if self.partial:
            out["partial"] = True
        return out

    def friction_record(self) -> dict[str, Any]:
        """The friction curve of the cycle as its own record (Zenoh key ``…/friction``)."""
        return {"schema": SCHEMA_VERSION, "robot": self.robot, "joint": self.joint, "cycle": self.cycle,
                "utc": self.utc, **self.friction}


@dataclass(frozen=True)
class Health:
    """The agent's health: frame and E2E counters, rates, queue depths, per-joint counters."""

    robot: str
    counters: dict[str, Any]
    utc: str | None = field(default_factory=utc_now)     # when the record was made (host clock)

    def to_dict(self) -> dict[str, Any]:
        return {"schema": SCHEMA_VERSION, "robot": self.robot, "utc": self.utc, **self.counters}

    def numbers(self) -> dict[str, float]:
        """The numeric top-level counters (for plotting)."""
        return {k: float(v) for k, v in self.counters.items()
                if isinstance(v, (int, float)) and not isinstance(v, bool)}
