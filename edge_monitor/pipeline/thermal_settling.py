"""Whether a joint's temperature has settled, from the motor temperature of its JointStatus frames (on a
joint whose controller sends none, the lubricant temperature read from the friction: ±1–3 °C per cycle,
as noisy as the motor's; :meth:`~edge_monitor.pipeline.joint_monitor.JointMonitor.joint_temperature`).

A joint warms for hours after a cold start (the simulator's lubricant: 30 → ≈ 58 °C with a time
constant of ≈ 200 cycles). The detectors' quantities move a little with the temperature, so a nominal
learned in the first cycles after commissioning, while the joint warms fastest, is not what the joint
shows once warm (docs/DETECTION.md, "Two stages"). :class:`ThermalSettling` says when the joint is
warm enough for the detectors to learn a nominal that stays representative: the least-squares slope of
the cycle-mean motor temperature over the last ``window`` cycles, plus ``z`` standard errors, is at
most ``max_rate`` [°C per cycle]; it stays settled until the slope *minus* ``z`` standard errors exceeds
``max_rate`` (the joint clearly warms again), so the noise of the test does not flicker the answer.
The per-cycle motor temperature scatters by ≈ 3 °C (it follows the cycle's load), hence a regression
over a long window rather than a difference of two cycles.

Bounded memory: a ring of ``window`` values.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from edge_monitor.errors import require
from edge_monitor.records import is_finite_number


@dataclass(frozen=True)
class SettlingConfig:
    """``window`` [cycles] of cycle-mean motor temperatures; settled when slope + ``z``·SE ≤ ``max_rate``
    [°C per cycle]. ``max_rate`` = 0.02: the steady nominal's 240 cycles then span ≈ 5 °C at most, and
    what warming is left after it is small enough for the steady calibration's drift (a test at 0.05
    over 120 cycles fired while the lubricant still had ≈ 3.3 °C to go, and the KL detectors ran at
    0.26–0.43× their stated run length; docs/DETECTION.md). 240 cycles keep 2 SE at ≈ 0.0056 °C/cycle
    for the simulator's 3 °C scatter, so a joint whose cycle-mean temperature scatters up to ≈ 10 °C
    still settles."""

    window: int = 240
    max_rate: float = 0.02
    z: float = 2.0

    def __post_init__(self) -> None:
        require(isinstance(self.window, int) and 20 <= self.window <= 10_000, "decision.settling_window",
                f"must be 20 … 10000 cycles, got {self.window!r}")
        require(isinstance(self.max_rate, (int, float)) and not isinstance(self.max_rate, bool)
                and 0 < self.max_rate <= 10, "decision.settling_max_rate",
                f"must be > 0 and ≤ 10 °C per cycle, got {self.max_rate!r}")
        require(isinstance(self.z, (int, float)) and 0 <= self.z <= 10, "z",
                f"must be 0 … 10 standard errors, got {self.z!r}")


class ThermalSettling:
    """``update(motor_temperature)`` → whether the joint's temperature has settled (see the module)."""

    def __init__(self, config: SettlingConfig = SettlingConfig()) -> None:
        self.config = config
        self._ring = np.full(config.window, np.nan)
        self._count = 0                      # values written (the ring's next slot is count % window)
        self.rate: float | None = None       # last slope [°C per cycle]
        self.rate_se: float | None = None    # its standard error
        self.settled = False

    def update(self, motor_temperature: float | None) -> bool:
        """Fold in one cycle's mean motor temperature [°C] (None or non-finite: the cycle is skipped)."""
        if motor_temperature is not None and math.isfinite(motor_temperature):
            self._ring[self._count % self.config.window] = float(motor_temperature)
            self._count += 1
            self._fit()
            self._decide()
        return self.settled

    def _decide(self) -> None:
        if self.rate is None or self.rate_se is None:
            return
        margin = self.config.z * self.rate_se
        if self.settled:
            self.settled = self.rate - margin <= self.config.max_rate
        else:
            self.settled = self.rate + margin <= self.config.max_rate

    def _fit(self) -> None:
        n = self.config.window
        if self._count < n:
            self.rate = self.rate_se = None
            return
        y = np.roll(self._ring, -(self._count % n))           # oldest first
        t = np.arange(n, dtype=float) - (n - 1) / 2.0
        sxx = float(t @ t)
        slope = float(t @ (y - y.mean())) / sxx
        residual = y - y.mean() - slope * t
        self.rate = slope
        self.rate_se = math.sqrt(float(residual @ residual) / (n - 2) / sxx)

    def status(self) -> dict[str, Any]:
        """For the symptom: settled, and the rate with its standard error [°C per cycle] once known."""
        return {"settled": self.settled, "rate": self.rate, "rate_se": self.rate_se}

    def recent(self) -> list[float]:
        """The temperatures in the window [°C], oldest first."""
        n = self.config.window
        kept = min(self._count, n)
        return (np.roll(self._ring, -(self._count % n))[n - kept:] if self._count >= n else self._ring[:kept]).tolist()

    # ------------------------------------------------------------------ persistence
    def state_dict(self) -> dict[str, Any]:
        return {"window": self.config.window, "count": self._count, "recent": self.recent(), "settled": self.settled}

    @classmethod
    def from_state(cls, config: SettlingConfig, state: dict[str, Any]) -> "ThermalSettling":
        """Restore; values saved with another window are replayed into this one (oldest dropped)."""
        out = cls(config)
        saved = state.get("recent")
        saved = saved if isinstance(saved, list) else []
        recent = [float(v) for v in saved if is_finite_number(v)]
        for value in recent[-config.window:]:
            out._ring[out._count % config.window] = value
            out._count += 1
        out._fit()
        out.settled = state.get("settled") is True and out.rate is not None    # a full window restored
        out._decide()
        return out
