"""A prior on the lubricant temperature from the motor temperature the controller reports.

The lubricant temperature ξ is not measured, and friction data alone cannot always tell a warm joint
from a worn one (docs/WEAR_ESTIMATION.md). The motor temperature of the JointStatus frame follows
the lubricant with an offset and per-cycle noise of a few °C (docs/studies/DISTURBANCE_STUDY.md:
correlation 0.82–0.87 per cycle, 0.97–0.985 averaged over 10 cycles). This component learns, over
the first ``learning_cycles`` cycles with both values, how the cycle's motor temperature relates to
the temperature the wear estimator finds from the friction data alone: ξ ≈ T_motor − offset with a
robust spread. After that it gives the wear estimator a Gaussian prior (T_motor − offset, spread).
Units: °C.

The motor temperature is deliberately not smoothed over cycles: a smoothed prior is more precise,
but its error is then correlated from cycle to cycle, and so are the wear estimates it informs (the
variance of 20-cycle means of the wear quantity was 2–3× that of independent values with an
exponential smoothing of 0.2 per cycle). The detectors' thresholds are calibrated for independent
cycles (docs/DETECTION.md), so the prior trades some precision for independence.
"""

from __future__ import annotations

import logging
import math
from typing import Any

import numpy as np

log = logging.getLogger(__name__)

#: Smallest prior spread [°C]: the motor winding is not the lubricant.
MIN_SPREAD = 1.0
#: Lowest plausible learned offset motor − lubricant [°C]. The motor is the heat source and warms the
#: gearbox, so its winding reads warmer than the lubricant (the simulator: +5 °C; healthy joints learn
#: +3.2 … +7.3, docs/WEAR_ESTIMATION.md §5). Friction above the nominal model is read as warm lubricant
#: by a fit with wear 0: a joint already worn to 35 when it is learned gives −5.9 … −1.5, one worn to
#: 20 gives −1.2 … +2.1 (seeds 0–1, 12 joints each).
MIN_PLAUSIBLE_OFFSET = 0.0


def implausible_offset(offset: float, spread: float) -> str | None:
    """Why a learned relation ξ ≈ motor − ``offset`` [°C] is suspect, or None when it is plausible."""
    if offset >= MIN_PLAUSIBLE_OFFSET:
        return None
    return (f"the friction it learned from reads as lubricant {-offset:.1f} °C (± {spread:.1f}) warmer than the "
            f"motor, which heats it: the joint's friction is above its nominal model. It may already be worn "
            f"(it is now learned as nominal, and wear is reported relative to it) or [friction] may not fit "
            f"this joint. Declare maintenance after servicing it, or check [friction]/[joint.N.friction]")


class MotorTemperaturePrior:
    """Learns ξ ≈ motor temperature − offset; ``prior()`` is (mean, std) or None while learning."""

    def __init__(self, learning_cycles: int = 20, label: str | None = None) -> None:
        self.learning_cycles = int(learning_cycles)
        self.label = label          # who learns it, for the log (e.g. "joint 2: …"); None: no warning
        self.motor: float | None = None
        self.offset: float | None = None
        self.spread: float | None = None
        self._pairs: list[tuple[float, float]] = []

    def observe_motor(self, motor_temperature: float | None) -> None:
        """The cycle's mean motor temperature [°C] (None or non-finite: no JointStatus this cycle)."""
        ok = motor_temperature is not None and math.isfinite(motor_temperature)
        self.motor = float(motor_temperature) if ok else None    # type: ignore[arg-type]

    def set_relation(self, offset: float, spread: float) -> None:
        """Adopt a relation learned elsewhere (the joint's model learning, which reports on it itself)."""
        self.offset, self.spread, self._pairs = float(offset), max(MIN_SPREAD, float(spread)), []
        self.label = None

    def prior(self) -> tuple[float, float] | None:
        """(mean, std) of ξ [°C] once learned and a motor temperature is known, else None."""
        if self.offset is None or self.spread is None or self.motor is None:
            return None
        return self.motor - self.offset, self.spread

    def learn(self, friction_temperature: float | None) -> None:
        """While learning: pair the wear estimator's own temperature (friction data only) with the
        motor temperature; the last pair fixes offset and spread."""
        if self.offset is not None or self.motor is None or friction_temperature is None \
                or not math.isfinite(friction_temperature):
            return
        self._pairs.append((self.motor, float(friction_temperature)))
        if len(self._pairs) >= self.learning_cycles:
            residual = np.array([m - f for m, f in self._pairs])
            self.offset = float(np.median(residual))
            self.spread = max(MIN_SPREAD, 1.4826 * float(np.median(np.abs(residual - self.offset))))
            self._pairs = []
            self._check("")

    def _check(self, when: str) -> None:
        """Log the relation once it is learned (or restored) if it is implausible and someone is named."""
        if self.label is not None and self.offset is not None and self.spread is not None:
            warning = implausible_offset(self.offset, self.spread)
            if warning:
                log.warning("%s%s: %s", self.label, when, warning)

    @property
    def learned(self) -> bool:
        return self.offset is not None

    def reset(self) -> None:
        """Declared maintenance: learn the relation again (a new gearbox, new lubricant)."""
        self.offset = self.spread = None
        self._pairs = []

    def state_dict(self) -> dict[str, Any]:
        return {"motor": self.motor, "offset": self.offset, "spread": self.spread,
                "pairs": [list(p) for p in self._pairs]}

    def load_state(self, state: dict[str, Any]) -> None:
        def number(key: str) -> float | None:
            value = state.get(key)
            return float(value) if isinstance(value, (int, float)) and math.isfinite(value) else None
        self.motor, self.offset, self.spread = number("motor"), number("offset"), number("spread")
        if (self.offset is None) != (self.spread is None):
            self.offset = self.spread = None
        self._check(" (learned before the restart)")
        pairs = state.get("pairs", [])
        self._pairs = [(float(a), float(b)) for a, b in pairs if math.isfinite(a) and math.isfinite(b)] \
            if isinstance(pairs, list) else []
