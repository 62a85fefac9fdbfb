"""The temperature the detectors' holds read: the joint's cycle temperature, smoothed over a few cycles and
following a stop at once (docs/DETECTION.md, "Operating conditions").

A cycle-mean motor temperature scatters by a few °C around the lubricant's slow course (the winding heats
with the cycle's load; the simulator: ± 3 °C from cycle to cycle, the lubricant moving ≈ 0.1 °C per
cycle). Read raw, that scatter widens the span a nominal was learned in (its lowest and highest cycles are
the scatter's extremes) and makes a hold flicker: after an overnight stop a joint 10 °C colder than its
nominal still had half its cycles inside the span, and those cycles raised false alarms. Smoothed, the
span is the lubricant's course plus about a third of the scatter, and a cycle is held or not as the
joint is.

:class:`HoldTemperature` is an exponential smoothing (``smoothing`` per cycle: the scatter's std shrinks by
√(a/(2 − a)), 0.38 at the default 0.25, and a steady warming lags ≈ (1 − a)/a = 3 cycles) that follows
a reading at once when it jumps further than ``jump_sigmas`` of the residuals' own spread (and at least
:data:`MIN_JUMP`): a stop, after which the joint is colder at once. The next reading tells a stop (it jumps
the same way: the smoothing restarts there) from a glitch (it is back: the smoothing goes on as before),
so one wild reading moves one cycle's temperature only. The smoothing only decides which
cycles the detectors test; the values they test are not smoothed, so consecutive decisions stay
independent (unlike a smoothed temperature prior, :mod:`edge_monitor.features.temperature_prior`).
The settling test (:mod:`~edge_monitor.pipeline.thermal_settling`) reads the raw cycles. Units: °C.
"""

from __future__ import annotations

import math
from typing import Any, TypeGuard

#: Smallest jump [°C] that restarts the smoothing: the floor of the holds' margin (a steadier sensor than
#: the simulator's would otherwise restart at every fraction of a degree).
MIN_JUMP = 2.0
#: Readings before the residuals' spread is trusted to call a jump (until then none restarts the smoothing).
SPREAD_READINGS = 8
#: Memory of the residuals' spread [cycles] (a running mean until then).
SPREAD_MEMORY = 32


class HoldTemperature:
    """``update(temperature) -> smoothed | None`` per cycle (None: unknown this cycle, state unchanged)."""

    def __init__(self, smoothing: float = 0.25, jump_sigmas: float = 4.0) -> None:
        if not 0.0 < smoothing <= 1.0:
            raise ValueError(f"smoothing: need 0 < a ≤ 1, got {smoothing!r}")
        self.smoothing = float(smoothing)
        self.jump_sigmas = float(jump_sigmas)
        self.level: float | None = None      # the smoothed temperature [°C]
        self.variance = 0.0                  # running mean square of the residuals [°C²]
        self.readings = 0                    # residuals in ``variance``
        self.pending: float | None = None    # a reading that jumped, until the next one confirms it [°C]
        self.jumps = 0                       # confirmed jumps so far (stops seen)

    def update(self, temperature: float | None) -> float | None:
        """Take one cycle's temperature [°C]; the smoothed one, or None when this cycle's is unknown. A
        reading that jumps is this cycle's temperature at once; the next reading confirms the jump (it jumps
        the same way: the level restarts between the two, :attr:`jumps` counts it) or shows a glitch (the
        level stays)."""
        if temperature is None or not math.isfinite(temperature):
            return None
        t = float(temperature)
        if self.level is None:
            self.level = t
            return t
        pending, self.pending = self.pending, None
        residual = t - self.level
        if pending is not None and abs(residual) > self._jump() and (residual > 0) == (pending > self.level):
            self.level = 0.5 * (pending + t)        # a stop: the joint is where the two readings say
            self.jumps += 1
            return self.level
        if self.readings >= SPREAD_READINGS and abs(residual) > self._jump():
            self.pending = t
            return t
        self.level += self.smoothing * residual
        self.variance += (residual * residual - self.variance) / min(self.readings + 1, SPREAD_MEMORY)
        self.readings += 1
        return self.level

    def _jump(self) -> float:
        """The smallest residual [°C] that is a jump."""
        return max(MIN_JUMP, self.jump_sigmas * math.sqrt(self.variance))

    def state_dict(self) -> dict[str, Any]:
        return {"level": self.level, "variance": self.variance, "readings": self.readings,
                "pending": self.pending, "jumps": self.jumps}

    @classmethod
    def from_state(cls, state: Any, smoothing: float = 0.25, jump_sigmas: float = 4.0) -> "HoldTemperature":
        """From :meth:`state_dict`; anything unusable (a state saved before the holds smoothed, a damaged
        value) starts afresh."""
        out = cls(smoothing, jump_sigmas)
        saved: dict[str, Any] = state if isinstance(state, dict) else {}
        level, variance, readings = saved.get("level"), saved.get("variance"), saved.get("readings")
        if _finite(level) and _finite(variance) and variance >= 0 and _count(readings):
            out.level, out.variance, out.readings = float(level), float(variance), readings
            pending, jumps = saved.get("pending"), saved.get("jumps")
            out.pending = float(pending) if _finite(pending) else None
            out.jumps = jumps if _count(jumps) else 0
        return out


def _count(x: Any) -> TypeGuard[int]:
    return isinstance(x, int) and not isinstance(x, bool) and x >= 0


def _finite(x: Any) -> TypeGuard[float]:
    return isinstance(x, (int, float)) and not isinstance(x, bool) and math.isfinite(x)
