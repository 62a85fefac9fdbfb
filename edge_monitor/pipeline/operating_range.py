"""The operating conditions a joint's detectors learned in, and the cycles outside them (docs/DETECTION.md,
"Operating conditions").

The detectors watch quantities made invariant to the measured operating conditions within the range
they were learned in: the wear likelihood marginalises the load, the KL distances are moved to the
reference load and temperature with the joint's friction model. Outside that range the invariance is
an extrapolation of the model, so the agent says so: per joint it keeps, for each covariate, the range
of the cycles its current nominals were learned from (:meth:`OperatingRange.update` with
``collecting`` while a detector collects nominal values, ``fitted`` when one fits its nominal), and
reports each cycle's covariates, which of them lie outside the learned range widened by a margin, and
an advisory when a covariate has left the range ("entered", after :data:`ENTER_CYCLES` cycles in a row
outside: one cycle's motor temperature scatters by ≈ 3 °C, and a single cycle beyond the margin is that
scatter, not a new condition) or is back for good ("left", after :data:`RETURN_CYCLES` cycles in a row
inside: a new load range that overlaps the learned one would otherwise flap between the two every few
cycles). The detectors keep monitoring (their
quantities are compensated, and holding them would blind the agent to wear during a new regime; where the
motor temperature is far from the one a nominal was learned at they test with a temperature slack,
:mod:`~edge_monitor.pipeline.nominal_temperature`); every alarm carries the covariates next to the learned
range. Only news makes an advisory: the temperatures a joint passes while it warms up after commissioning or
a maintenance are its usual path (they widen the learned range), so a cold restart after a stop, back along
that path, is not news; a hotter day than any seen, or a load never learned, is.

Covariates: ``load`` — |load torque| of the cycle (measured at the plateaus, else the controller's
estimate; dimensionless); ``motor_temperature`` — the cycle's mean motor temperature [°C].
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any, Collection

from edge_monitor.features.base import CycleInput

#: Covariates tracked, and the smallest margin around a learned range that still counts as inside:
#: a load 0.02 (≈ the scatter of the plateau measurement and the wire resolution many times over),
#: a motor temperature 2 °C (its per-cycle scatter is ≈ 3 °C in the simulator).
MARGINS: dict[str, float] = {"load": 0.02, "motor_temperature": 2.0}
#: Margin as a fraction of the learned span (the larger of the two applies).
RELATIVE_MARGIN = 0.1
#: Cycles in a row inside the learned range before an advisory says the covariate is back.
RETURN_CYCLES = 20
#: Cycles in a row outside it before an advisory says the covariate has left it (a new load or a hotter
#: hall stays outside; one cycle's scatter does not: 3 in a row beyond the margin by chance is rare).
ENTER_CYCLES = 3


@dataclass
class Span:
    """The range [lo, hi] of a covariate's values (empty until one is added)."""

    lo: float = math.inf
    hi: float = -math.inf

    def add(self, value: float) -> None:
        self.lo, self.hi = min(self.lo, value), max(self.hi, value)

    @property
    def empty(self) -> bool:
        return self.lo > self.hi

    def margin(self, covariate: str) -> float:
        """How far outside it a value of ``covariate`` may lie and still count as inside."""
        return max(MARGINS[covariate], RELATIVE_MARGIN * (self.hi - self.lo))


@dataclass(frozen=True)
class RangeEvent:
    """A covariate left (``"entered"`` the outside) or came back into its learned range."""

    covariate: str
    state: str                    # "entered" | "left"
    value: float
    learned: tuple[float, float]


@dataclass
class OperatingRange:
    """See the module docstring."""

    learned: dict[str, Span] = field(default_factory=dict)
    collecting: dict[str, Span] = field(default_factory=dict)
    advised: dict[str, int] = field(default_factory=dict)  # open advisories: cycles in a row back inside
    was_collecting: bool = False
    now_outside: set[str] = field(default_factory=set)     # covariates outside in the last cycle
    usual: dict[str, Span] = field(default_factory=dict)    # values seen on the joint's usual path (``update``)
    entering: dict[str, int] = field(default_factory=dict)  # cycles in a row outside, before an advisory

    def _widened(self, name: str, span: Span) -> Span:
        """A new learned range: ``span``, and the usual path seen so far."""
        out = Span(span.lo, span.hi)
        usual = self.usual.get(name)
        if usual is not None and not usual.empty:
            out.add(usual.lo)
            out.add(usual.hi)
        return out

    def update(self, values: dict[str, float | None], collecting: bool, fitted: bool,
               usual: Collection[str] = ()) -> list[RangeEvent]:
        """One cycle's covariates; ``collecting``: its values went into a nominal being learned;
        ``fitted``: a nominal was fitted this cycle. The detectors of a joint learn together but fit
        one after the other (their inputs start at different cycles), so a learning period — the
        cycles while any detector collects — is one range, and every fit in it makes that range, as
        collected so far, the learned one; a new period (after a pause) starts a new range. ``usual``:
        covariates whose value this cycle may be on the joint's usual path (the motor temperature while the joint
        warms up after commissioning or a maintenance: the detectors' temperature slack covers it): a value
        within twice the margin of the learned range widens it instead of making an advisory (a jump further is
        still news); a later nominal keeps what was so widened."""
        known = {k: float(v) for k, v in values.items() if v is not None and math.isfinite(v) and k in MARGINS}
        if collecting and not self.was_collecting:
            self.collecting = {}
        self.was_collecting = collecting
        if collecting:
            for name, value in known.items():
                self.collecting.setdefault(name, Span()).add(value)
        refit = fitted and bool(self.collecting)
        if refit:
            self.learned = {name: self._widened(name, span) for name, span in self.collecting.items()}
        for name in usual:                   # a continuous path: within twice the margin of where it has been
            span = self.learned.get(name)
            if name in known and span is not None and not span.empty and \
                    span.lo - 2 * span.margin(name) <= known[name] <= span.hi + 2 * span.margin(name):
                span.add(known[name])
                self.usual.setdefault(name, Span()).add(known[name])
        self.now_outside = {name for name, value in known.items() if self._beyond(name, value)}
        return [event for name, value in known.items() if (event := self._advise(name, value, refit)) is not None]

    def _beyond(self, name: str, value: float) -> bool:
        span = self.learned.get(name)
        if span is None or span.empty:
            return False
        margin = span.margin(name)
        return not span.lo - margin <= value <= span.hi + margin

    def _advise(self, name: str, value: float, refit: bool) -> RangeEvent | None:
        """The advisory event of ``name`` this cycle, if any; a new learned range (``refit``) that holds
        the value closes an open advisory at once."""
        span = self.learned.get(name)
        if name not in self.advised:
            if name not in self.now_outside:
                self.entering.pop(name, None)
                return None
            self.entering[name] = self.entering.get(name, 0) + 1
            if self.entering[name] < ENTER_CYCLES:
                return None
            del self.entering[name]
            self.advised[name] = 0
            return RangeEvent(name, "entered", value, (span.lo, span.hi)) if span else None
        back = self.advised[name] = 0 if name in self.now_outside else self.advised[name] + 1
        if back >= RETURN_CYCLES or span is None or (refit and back):
            del self.advised[name]
            return RangeEvent(name, "left", value, (span.lo, span.hi)) if span else None
        return None

    def section(self, values: dict[str, float | None]) -> dict[str, Any]:
        """The symptom's ``operating`` section: the covariates, the learned ranges, those outside."""
        return {"covariates": {k: v for k, v in values.items() if k in MARGINS},
                "learned": {k: [s.lo, s.hi] for k, s in self.learned.items() if not s.empty},
                "outside": sorted(self.now_outside)}

    def reset(self) -> None:
        """A declared maintenance: the nominals are learned again, and so is their range."""
        self.learned, self.collecting, self.advised, self.was_collecting = {}, {}, {}, False
        self.now_outside, self.usual, self.entering = set(), {}, {}

    def state_dict(self) -> dict[str, Any]:
        return {"learned": {k: [s.lo, s.hi] for k, s in self.learned.items() if not s.empty},
                "collecting": {k: [s.lo, s.hi] for k, s in self.collecting.items() if not s.empty},
                "outside": sorted(self.advised), "inside_run": dict(self.advised),
                "was_collecting": self.was_collecting, "entering": dict(self.entering),
                "usual": {k: [s.lo, s.hi] for k, s in self.usual.items() if not s.empty}}

    @classmethod
    def from_state(cls, state: Any) -> "OperatingRange":
        """Restore; an unusable state gives an empty range (learned again with the next nominals)."""
        out = cls()
        if not isinstance(state, dict):
            return out
        for key in ("learned", "collecting", "usual"):
            spans = state.get(key)
            if isinstance(spans, dict):
                getattr(out, key).update({name: Span(float(v[0]), float(v[1])) for name, v in spans.items()
                                          if name in MARGINS and is_span(v)})
        outside, runs = state.get("outside"), state.get("inside_run")
        if isinstance(outside, list):            # a state saved before "inside_run" has no counts: 0
            runs = runs if isinstance(runs, dict) else {}
            out.advised = {name: n if isinstance(n := runs.get(name, 0), int) and 0 <= n < RETURN_CYCLES else 0
                           for name in outside if name in out.learned}
        out.was_collecting = state.get("was_collecting") is True
        entering = state.get("entering")             # a state saved before it has none: counted afresh
        if isinstance(entering, dict):
            out.entering = {name: n for name, n in entering.items() if name in MARGINS and name not in out.advised
                            and isinstance(n, int) and not isinstance(n, bool) and 0 < n < ENTER_CYCLES}
        return out


def cycle_covariates(cycle: CycleInput) -> dict[str, float | None]:
    """A cycle's operating conditions: |load torque| (measured at the plateaus, else the controller's estimate)
    and the mean motor temperature [°C]."""
    load = cycle.friction.load_torque if cycle.friction.load_torque is not None else cycle.load_mean
    return {"load": None if load is None else abs(load), "motor_temperature": cycle.motor_temperature}


def is_span(value: Any) -> bool:
    """Whether a saved value is a span: [lo, hi], finite numbers, lo ≤ hi."""
    return (isinstance(value, list) and len(value) == 2
            and all(isinstance(x, (int, float)) and math.isfinite(x) for x in value) and value[0] <= value[1])
