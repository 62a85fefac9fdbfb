"""Wear scenarios: the wear level ϖ (0 … 100, 35 = critical) of a joint as a function of the cycle.

A :class:`WearProfile` starts at ``initial`` and applies its events in order; an event that has
started overrides the value of the events before it, so scenarios compose (e.g. a ramp, then a
gearbox replacement at cycle 800, then a new ramp). Event kinds:

* ``ramp``        linear from ``start`` to ``end`` cycle, ``from_`` → ``to``
* ``exponential`` accelerated-wear onset: ``from_ + (to − from_)·(e^{(c−start)/tau} − 1)/(e^{(end−start)/tau} − 1)``
* ``power``       power law from ``start`` to ``end``: ``from_ + (to − from_)·x^exponent``,
  ``x = (c − start)/(end − start)`` (``exponent`` > 1 accelerates, < 1 decelerates)
* ``step``        abrupt change to ``to`` at cycle ``start``
* ``replacement`` gearbox replaced before cycle ``start``: wear back to 0 (declared maintenance)
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, Literal, Mapping

KINDS = ("ramp", "exponential", "power", "step", "replacement")
#: Kinds that go from ``from_`` at ``start`` to ``to`` at ``end``.
SPANNING = ("ramp", "exponential", "power")
MAX_WEAR = 100.0


class WearScenarioError(ValueError):
    """Invalid wear scenario; the message names the field."""


def _check_wear(value: float, field_name: str) -> float:
    if not (isinstance(value, (int, float)) and math.isfinite(value) and 0.0 <= value <= MAX_WEAR):
        raise WearScenarioError(f"{field_name}: wear must be 0 … {MAX_WEAR:g}, got {value!r}")
    return float(value)


def _check_cycle(value: Any, field_name: str) -> int:
    if isinstance(value, bool) or not isinstance(value, (int, float)) or value != int(value) or value < 0:
        raise WearScenarioError(f"{field_name}: expected a cycle number ≥ 0, got {value!r}")
    return int(value)


@dataclass(frozen=True)
class WearEvent:
    """One wear event (see module docstring). Cycles are 0-based test-cycle numbers."""

    kind: Literal["ramp", "exponential", "power", "step", "replacement"]
    start: int
    end: int | None = None
    from_: float = 0.0
    to: float = 0.0
    tau: float = 50.0   # exponential growth constant [cycles]
    exponent: float = 2.0   # power-law exponent (dimensionless)

    def __post_init__(self) -> None:
        where = f"wear.{self.kind}"
        if self.kind not in KINDS:
            raise WearScenarioError(f"wear.kind: unknown kind {self.kind!r}; use one of {list(KINDS)}")
        _check_cycle(self.start, f"{where}.start")
        _check_wear(self.from_, f"{where}.from")
        _check_wear(self.to, f"{where}.to")
        if self.kind in SPANNING:
            if self.end is None:
                raise WearScenarioError(f"{where}.end: required for {self.kind}")
            _check_cycle(self.end, f"{where}.end")
            if self.end < self.start:
                raise WearScenarioError(f"{where}.end: must be ≥ start ({self.start}), got {self.end}")
        if self.kind == "exponential" and not (math.isfinite(self.tau) and self.tau > 0):
            raise WearScenarioError(f"{where}.tau: must be > 0 cycles, got {self.tau!r}")
        if self.kind == "power" and not (math.isfinite(self.exponent) and 0.05 <= self.exponent <= 20):
            raise WearScenarioError(f"{where}.exponent: must be 0.05 … 20, got {self.exponent!r}")

    def value(self, cycle: int) -> float | None:
        """Wear at ``cycle`` if the event has started, else ``None``."""
        if cycle < self.start:
            return None
        if self.kind == "replacement":
            return 0.0
        if self.kind == "step":
            return self.to
        assert self.end is not None
        if cycle >= self.end or self.end == self.start:
            return self.to
        x = (cycle - self.start) / (self.end - self.start)
        if self.kind == "ramp":
            return self.from_ + (self.to - self.from_) * x
        if self.kind == "power":
            return self.from_ + (self.to - self.from_) * x ** self.exponent
        span = (self.end - self.start) / self.tau       # expm1(x·span)/expm1(span), written not to overflow
        share = math.exp(span * (x - 1)) * math.expm1(-x * span) / math.expm1(-span)
        return self.from_ + (self.to - self.from_) * share

    def to_dict(self) -> dict[str, Any]:
        d: dict[str, Any] = {"kind": self.kind, "start": self.start}
        if self.kind in SPANNING:
            d.update(end=self.end, **{"from": self.from_}, to=self.to)
        if self.kind == "exponential":
            d["tau"] = self.tau
        if self.kind == "power":
            d["exponent"] = self.exponent
        if self.kind == "step":
            d["to"] = self.to
        return d


@dataclass(frozen=True)
class WearProfile:
    """Wear of one joint over cycles: ``initial`` then ``events`` applied in order."""

    initial: float = 0.0
    events: tuple[WearEvent, ...] = ()

    def __post_init__(self) -> None:
        _check_wear(self.initial, "wear.initial")

    def wear(self, cycle: int) -> float:
        value = self.initial
        for event in self.events:
            v = event.value(cycle)
            if v is not None:
                value = v
        return value

    def maintenance(self, cycle: int) -> bool:
        """True on the first cycle after a gearbox replacement (the declared maintenance)."""
        return any(e.kind == "replacement" and e.start == cycle for e in self.events)

    def to_dict(self) -> dict[str, Any]:
        return {"initial": self.initial, "events": [e.to_dict() for e in self.events]}


def _joint(text: str, option: str) -> int | Literal["all"]:
    """The JOINT part of a command-line wear option: a joint index ≥ 0 or ``all``."""
    if text.strip().lower() == "all":
        return "all"
    try:
        joint = int(text)
    except ValueError:
        raise WearScenarioError(f"{option}: JOINT must be an integer or 'all', got {text!r}") from None
    if joint < 0:
        raise WearScenarioError(f"{option}: unknown joint {joint}")
    return joint


def parse_wear_ramp(text: str) -> tuple[int | Literal["all"], WearEvent]:
    """``JOINT:START_CYCLE:END_CYCLE:FROM:TO`` (JOINT 0-based or ``all``) → (joint, ramp event)."""
    parts = text.split(":")
    if len(parts) != 5:
        raise WearScenarioError(f"wear_ramp: expected JOINT:START_CYCLE:END_CYCLE:FROM:TO, got {text!r}")
    joint_text, start, end, wfrom, wto = parts
    joint = _joint(joint_text, "wear_ramp")
    try:
        start_i, end_i = int(start), int(end)
        from_f, to_f = float(wfrom), float(wto)
    except ValueError:
        raise WearScenarioError(f"wear_ramp: START/END must be integers and FROM/TO numbers, got {text!r}") from None
    try:
        event = WearEvent("ramp", start=start_i, end=end_i, from_=from_f, to=to_f)
    except WearScenarioError as exc:
        raise WearScenarioError(f"wear_ramp {text!r}: {exc}") from None
    return joint, event


def event_from_mapping(doc: Mapping[str, Any], where: str) -> WearEvent:
    """A scenario-file table ``{kind, start, end?, from?, to?, tau?}`` → :class:`WearEvent`."""
    known = {"kind", "start", "end", "from", "to", "tau", "exponent", "cycle"}
    unknown = sorted(set(doc) - known)
    if unknown:
        raise WearScenarioError(f"{where}: unknown field(s) {unknown}; known: {sorted(known)}")
    kind = doc.get("kind")
    if kind not in KINDS:
        raise WearScenarioError(f"{where}.kind: expected one of {list(KINDS)}, got {kind!r}")
    start = doc.get("start", doc.get("cycle"))
    if start is None:
        raise WearScenarioError(f"{where}.start: required (first cycle of the {kind})")
    numbers = {}
    for name in ("from", "to", "tau", "exponent"):
        if name in doc:
            value = doc[name]
            if isinstance(value, bool) or not isinstance(value, (int, float)):
                raise WearScenarioError(f"{where}.{name}: expected a number, got {value!r}")
            numbers[name] = float(value)
    end = doc.get("end")
    try:
        return WearEvent(kind, start=_check_cycle(start, f"{where}.start"),
                         end=None if end is None else _check_cycle(end, f"{where}.end"),
                         from_=numbers.get("from", 0.0), to=numbers.get("to", 0.0), tau=numbers.get("tau", 50.0),
                         exponent=numbers.get("exponent", 2.0))
    except WearScenarioError as exc:
        raise WearScenarioError(f"{where}: {exc}") from None


def parse_wear_law(text: str) -> tuple[int | Literal["all"], WearEvent]:
    """``JOINT:KIND:KEY=VALUE[,KEY=VALUE…]`` (JOINT 0-based or ``all``; the keys of a scenario file's wear
    table: ``start``, ``end``, ``from``, ``to``, ``tau``, ``exponent``) → (joint, event), e.g.
    ``2:power:start=100,end=900,from=0,to=60,exponent=2`` or ``all:step:start=300,to=12``."""
    joint_text, sep, rest = text.partition(":")
    kind, sep2, pairs = rest.partition(":")
    if not sep or not sep2 or not kind.strip():
        raise WearScenarioError(f"wear_law: expected JOINT:KIND:KEY=VALUE[,KEY=VALUE...], got {text!r}")
    joint = _joint(joint_text, "wear_law")
    doc: dict[str, Any] = {"kind": kind.strip()}
    for pair in filter(None, (p.strip() for p in pairs.split(","))):
        key, eq, value = (part.strip() for part in pair.partition("="))
        if not eq or not key:
            raise WearScenarioError(f"wear_law {text!r}: expected KEY=VALUE, got {pair!r}")
        try:
            doc[key] = int(value) if key in ("start", "end") else float(value)
        except ValueError:
            raise WearScenarioError(f"wear_law {text!r}: {key} needs a number, got {value!r}") from None
    try:
        return joint, event_from_mapping(doc, "wear_law")
    except WearScenarioError as exc:
        raise WearScenarioError(f"{exc} (in --wear-law {text!r})") from None
