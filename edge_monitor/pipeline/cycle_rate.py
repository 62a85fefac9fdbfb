"""The test-cycle rate a robot really runs at, for its false-alarm budget (docs/DETECTION.md, "The
false-alarm budget").

The budget is stated per robot and period (``[decision] false_alarms_per_robot`` per ``budget_period``);
turning it into a mean run length per detector needs the number of test cycles a day.
:class:`CycleRate` counts the cycles that end in each hour of the frames' clock (bus or log time) and
reports the count of the last 24 complete hours: bounded memory (25 counters, whatever the rate). A
clock that jumps back by more than an hour (a log from another day, a reset controller clock) starts
the count again. :class:`BudgetRate` converts the budget at the configured ``cycles_per_day`` until a
full day has been counted, then at the measured rate whenever it leaves ±25 % of the rate the
thresholds were derived for; the agent then re-derives every threshold on the same learned nominals.
Where neither the config nor a mapping states the robot's joints (``[decision] joints_per_robot`` unset:
a robot on our native frames), the budget is split over the joints seen, counted as they appear.
"""

from __future__ import annotations

import logging
import math
from typing import Any

from edge_monitor.pipeline.decision_config import MAX_JOINTS_PER_ROBOT, DecisionConfig
from edge_monitor.stats.calibration import MAX_ARL0, MIN_ARL0

log = logging.getLogger(__name__)

HOUR_S = 3600.0
DAY_HOURS = 24
#: The thresholds are re-derived when the measured rate leaves ±this fraction of the one they are for.
RATE_TOLERANCE = 0.25


class CycleRate:
    """Test cycles a day from the end times of the cycles: hourly counts over the last 24 complete hours.

    ``update(t)`` [s, any epoch] → the cycles of the last 24 complete hours, or None until 24 complete
    hours have passed since the first cycle counted."""

    def __init__(self) -> None:
        self._counts = [0] * (DAY_HOURS + 1)
        self._hour: int | None = None          # the hour of the latest cycle (the one being counted)
        self._first: int | None = None         # the hour counting began in (partial: not reported)

    def update(self, t: float) -> float | None:
        if not math.isfinite(t) or abs(t) > 1e13:
            return self.rate
        hour = int(t // HOUR_S)
        if self._hour is None or hour < self._hour - 1:
            self._counts = [0] * len(self._counts)
            self._hour = self._first = hour
        elif hour > self._hour:
            for h in range(self._hour + 1, min(hour, self._hour + len(self._counts)) + 1):
                self._counts[h % len(self._counts)] = 0
            self._hour = hour
        self._counts[self._hour % len(self._counts)] += 1
        return self.rate

    @property
    def rate(self) -> float | None:
        """Cycles in the last 24 complete hours, or None before a full day was seen."""
        if self._hour is None or self._first is None or self._hour - self._first <= DAY_HOURS:
            return None
        return float(sum(self._counts) - self._counts[self._hour % len(self._counts)])

    def state_dict(self) -> dict[str, Any]:
        return {"counts": list(self._counts), "hour": self._hour, "first": self._first}

    @classmethod
    def from_state(cls, state: dict[str, Any]) -> "CycleRate":
        """Restore; ``ValueError`` for a state no counter could have saved."""
        out = cls()
        counts, hour, first = state.get("counts"), state.get("hour"), state.get("first")
        ok = (isinstance(counts, list) and len(counts) == len(out._counts)
              and all(isinstance(c, int) and not isinstance(c, bool) and 0 <= c < 2**53 for c in counts)
              and (hour is None) == (first is None)
              and all(h is None or (isinstance(h, int) and abs(h) < 2**40) for h in (hour, first)))
        if not ok or (hour is not None and first is not None and first > hour):
            raise ValueError("saved cycle rate: not a state a cycle counter could have saved")
        out._counts, out._hour, out._first = [int(c) for c in counts or []], hour, first
        return out


class BudgetRate:
    """The cycle rate the robot's false-alarm budget is converted at, and the ARL0 it gives.

    ``update(t)`` counts a cycle ending at ``t`` [s] and returns the new mean run length per detector
    [cycles] when the thresholds must be re-derived (the measured rate left ±``RATE_TOLERANCE`` of
    :attr:`basis`), else None; ``count_joints(n)`` does the same when the budget is split over the joints
    seen and their number changed. A fixed ``arl0_cycles`` is never re-derived."""

    def __init__(self, decision: DecisionConfig) -> None:
        self.decision = decision
        self.counter = CycleRate()
        self.basis = decision.cycles_per_day      # cycles a day the thresholds are derived for
        self.measured = False                     # whether the basis was measured (else configured)
        self.rederived = 0
        self.joints_seen: int | None = None       # joints counted (only where joints_per_robot is unset)

    @property
    def joints(self) -> int:
        """The joints the budget is split over: ``joints_per_robot`` if stated, else the joints seen (6 before
        any is seen)."""
        if self.decision.joints_per_robot is not None or self.joints_seen is None:
            return self.decision.budget_joints
        return self.joints_seen

    @property
    def arl0(self) -> float:
        """The mean run length per detector [cycles] the thresholds should be calibrated for now."""
        return min(max(self.decision.arl0_for(self.basis, self.joints), MIN_ARL0), MAX_ARL0)

    def count_joints(self, seen: int) -> float | None:
        """The robot's joints seen so far (``seen`` ≥ 1): the new ARL0 [cycles] when it moved the split of
        the budget, else None (the joints are stated, or fixed ``arl0_cycles``, or the count is the same)."""
        seen = min(max(int(seen), 1), MAX_JOINTS_PER_ROBOT)
        if self.decision.joints_per_robot is not None or seen == self.joints_seen:
            return None
        old, self.joints_seen = self.arl0, seen
        return None if self.arl0 == old else self.arl0

    @property
    def fixed(self) -> bool:
        return self.decision.arl0_cycles is not None or self.decision.pf is not None

    @property
    def cycles_per_day(self) -> float:
        """Test cycles a day as measured over the last 24 complete hours; while none is measured, or none
        ran in them (a weekend), :attr:`basis` (the configured rate, or the last one measured outside its
        tolerance). The prognosis counts days at it."""
        return self.counter.rate or self.basis

    def update(self, t: float | None) -> float | None:
        if t is None:
            return None
        rate = self.counter.update(t)
        if self.fixed or rate is None or rate <= 0 or abs(rate / self.basis - 1.0) <= RATE_TOLERANCE:
            return None
        old_basis, old = self.basis, self.arl0
        self.basis, self.measured = rate, True
        self.rederived += 1
        log.warning("measured %.0f test cycles a day (thresholds were for %.0f): re-deriving every threshold "
                     "for %.3g cycles per detector (was %.3g)%s", rate, old_basis, self.arl0, old,
                     "; capped at the largest ARL0 calibrated" if self.arl0 == MAX_ARL0 else "")
        return self.arl0

    def counters(self) -> dict[str, Any]:
        return {"cycles_per_day": self.basis, "cycles_per_day_measured": self.counter.rate,
                "arl0_cycles": self.arl0, "threshold_rederivations": self.rederived, "budget_joints": self.joints}

    def state_dict(self) -> dict[str, Any]:
        return {"counter": self.counter.state_dict(), "basis": self.basis if self.measured else None,
                "rederived": self.rederived}

    def load_state(self, state: Any) -> None:
        """Restore what was measured (a damaged entry only restarts the count, with a warning)."""
        try:
            counter = CycleRate.from_state(state["counter"])
            basis = state.get("basis")
            if basis is not None and not (isinstance(basis, (int, float)) and 0 < basis <= 1e9):
                raise ValueError(f"saved cycle rate basis {basis!r}")
            rederived = int(state.get("rederived", 0))
        except (KeyError, TypeError, ValueError, AttributeError) as exc:
            log.warning("saved cycle rate unusable (%s); measuring it again", exc)
            return
        self.counter, self.rederived = counter, rederived
        if basis is not None:
            self.basis, self.measured = float(basis), True
