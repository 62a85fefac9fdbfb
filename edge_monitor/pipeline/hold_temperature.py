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
:data:`MIN_JUMP`). The next reading tells a lasting jump (it jumps the same way: the smoothing restarts
there; a stop, after which the joint is colder at once, if it is down by more than :data:`CONFIRM_SIGMAS`)
from a glitch (it is back: the smoothing goes on as before), so one wild reading moves one cycle's
temperature only. The smoothing only decides which
cycles the detectors test; the values they test are not smoothed, so consecutive decisions stay
independent (unlike a smoothed temperature prior, :mod:`edge_monitor.features.temperature_prior`).
The settling test (:mod:`~edge_monitor.pipeline.thermal_settling`) reads the raw cycles. Units: °C.
"""

from __future__ import annotations

import math
from typing import Any, TypeGuard

from edge_monitor.records import is_count, is_finite_number

#: Smallest jump [°C] that restarts the smoothing: the floor of the holds' margin (a steadier sensor than
#: the simulator's would otherwise restart at every fraction of a degree).
MIN_JUMP = 2.0
#: Readings before the residuals' spread is trusted to call a jump and count a stop; until then a jump is
#: a residual beyond :data:`EARLY_JUMP` [°C] (one wild reading in the first cycles would otherwise enter the
#: level and the spread whole).
SPREAD_READINGS = 32
EARLY_JUMP = 10.0
#: Memory of the residuals' spread [cycles] (a running mean until then).
SPREAD_MEMORY = 32
#: How far below the level the mean of a jumping reading and the confirming next one must be [residual
#: stds] to count a stop (each alone: ``jump_sigmas``): two readings of Gaussian scatter hardly ever get
#: there together. A smaller confirmed jump moves the level, but restarts no settling.
CONFIRM_SIGMAS = 4.0
#: Plausible temperatures [°C] and spread [°C²] of a saved state (beyond them it starts afresh).
PLAUSIBLE = (-100.0, 300.0)
MAX_VARIANCE = 1.0e6


class HoldTemperature:
    """``update(temperature) -> smoothed | None`` per cycle (None: unknown this cycle, state unchanged)."""

    def __init__(self, smoothing: float = 0.25, jump_sigmas: float = 3.0) -> None:
        if not 0.0 < smoothing <= 1.0:
            raise ValueError(f"smoothing: need 0 < a ≤ 1, got {smoothing!r}")
        self.smoothing = float(smoothing)
        self.jump_sigmas = float(jump_sigmas)
        self.level: float | None = None      # the smoothed temperature [°C]
        self.variance = 0.0                  # running mean square of the residuals [°C²]
        self.readings = 0                    # residuals in ``variance``
        self.pending: float | None = None    # a reading that jumped, until the next one confirms it [°C]
        self.jumps = 0                       # confirmed jumps so far, either way
        self.stops = 0                       # confirmed jumps down: the joint cooled at once (a stop)

    def update(self, temperature: float | None) -> float | None:
        """Take one cycle's temperature [°C]; the smoothed one, or None when this cycle's is unknown. A
        reading that jumps is this cycle's temperature at once; the next reading confirms the jump (it jumps
        the same way and agrees with it: the level restarts between the two and :attr:`jumps` counts it;
        :attr:`stops` too if the two's mean is below the level by more than :data:`CONFIRM_SIGMAS`) or
        shows a glitch (the level stays)."""
        if not _plausible(temperature):        # unknown, or no temperature a joint has: a counted drop upstream
            return None
        t = float(temperature)
        if self.level is None:
            self.level = t
            return t
        pending, self.pending = self.pending, None
        residual, jump = t - self.level, self._jump()
        if pending is not None and abs(residual) > jump and (residual > 0) == (pending > self.level) \
                and abs(t - pending) <= jump:
            shift = 0.5 * (t + pending) - self.level
            self.stops += self.readings >= SPREAD_READINGS and shift < -self._jump(CONFIRM_SIGMAS)
            self.jumps += 1
            self.level += shift                     # the joint is where the two readings say
            return self.level
        if abs(residual) > jump:
            self.pending = t
            return t
        self.level += self.smoothing * residual
        self.variance += (residual * residual - self.variance) / min(self.readings + 1, SPREAD_MEMORY)
        self.readings += 1
        return self.level

    @property
    def confirmed(self) -> bool:
        """Whether the last reading is part of the smoothed course (not a jump awaiting confirmation)."""
        return self.pending is None

    def _jump(self, sigmas: float | None = None) -> float:
        """The smallest residual [°C] that is a jump (``sigmas`` of the residuals' spread, at least
        :data:`MIN_JUMP`; default :attr:`jump_sigmas`; :data:`EARLY_JUMP` until the spread is trusted)."""
        if self.readings < SPREAD_READINGS:
            return EARLY_JUMP
        return max(MIN_JUMP, (self.jump_sigmas if sigmas is None else sigmas) * math.sqrt(self.variance))

    def state_dict(self) -> dict[str, Any]:
        return {"level": self.level, "variance": self.variance, "readings": self.readings,
                "pending": self.pending, "jumps": self.jumps, "stops": self.stops}

    @classmethod
    def from_state(cls, state: Any, smoothing: float = 0.25, jump_sigmas: float = 3.0) -> "HoldTemperature":
        """From :meth:`state_dict`; anything unusable (a state saved before the holds smoothed, a damaged or
        implausible value) starts afresh."""
        out = cls(smoothing, jump_sigmas)
        saved: dict[str, Any] = state if isinstance(state, dict) else {}
        level, variance, readings = saved.get("level"), saved.get("variance"), saved.get("readings")
        if _plausible(level) and is_finite_number(variance) and 0 <= variance <= MAX_VARIANCE and is_count(readings):
            out.level, out.variance, out.readings = float(level), float(variance), readings
            pending = saved.get("pending")
            out.pending = float(pending) if _plausible(pending) else None
            out.jumps = saved["jumps"] if is_count(saved.get("jumps")) else 0
            out.stops = saved["stops"] if is_count(saved.get("stops")) else 0
        return out

    @classmethod
    def replayed(cls, temperatures: list[float]) -> "HoldTemperature":
        """A fresh smoothing fed ``temperatures`` (oldest first): for a state saved before the holds
        smoothed, from the settling test's recent history, so a stop right after the upgrade is still seen."""
        out = cls()
        for t in temperatures[-(SPREAD_READINGS + 1):]:
            out.update(t)
        out.jumps = out.stops = 0
        return out


def _plausible(x: Any) -> TypeGuard[float]:
    return is_finite_number(x) and PLAUSIBLE[0] <= x <= PLAUSIBLE[1]
