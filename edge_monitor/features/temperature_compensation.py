"""Torque samples moved to a reference lubricant temperature with the joint's friction model.

Temperature changes friction as much as critical wear does (docs/studies/DISTURBANCE_STUDY.md): at low
speed friction rises with ξ, at high speed the viscous slope falls. A distribution-domain detector
that compares each cycle's torque density with a nominal one learned at the start of a shift sees
that as a change. The friction model knows how friction depends on ξ, so each sample is moved to the
reference temperature ξref (the joint's temperature when its nominal density was learned):

    τ ← τ − sign(v)·[τ0(|v|, ξc) − τ0(|v|, ξref)]

with ξc the joint's current lubricant temperature, estimated from the friction data of the previous
cycles (the wear feature's ξ̂, smoothed exponentially: the lubricant moves ≲ 0.1 °C per cycle). The
load terms of τ0 do not depend on ξ and cancel; wear is not touched.

While the joint stands (a pause in its samples, :meth:`TemperatureCompensation.cool`) the lubricant cools
towards the coldest temperature the joint has shown (its idle temperature, ≈ ambient) with the thermal
time constant (≈ 3 h): ξc ← ξamb + (ξc − ξamb)·exp(−pause/τth). Without that the smoothed ξ̂ of the warm
joint compensated the first cycles after an overnight stop by ≈ 25 °C too much: the KL distances stood
3–7 σ above their nominal for ≈ 10 cycles (plant-week scenario, every long stop). Units: torque
dimensionless, speed rad/s, temperature °C, time s.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
from numpy.typing import NDArray

from joint_model import FrictionParams, nominal_friction


class TemperatureCompensation:
    """See the module docstring. ``smoothing``: weight of the newest cycle's ξ̂ in the running estimate."""

    def __init__(self, params: FrictionParams, smoothing: float = 0.2) -> None:
        self.params = params
        self.smoothing = float(smoothing)
        self.reference: float | None = None
        self.current: float | None = None
        self.coldest: float | None = None          # lowest smoothed ξ so far: the idle temperature a pause cools to

    def cool(self, seconds: float, time_constant_s: float) -> None:
        """The joint stood still for ``seconds``: its lubricant cooled towards :attr:`coldest` with the time
        constant ``time_constant_s`` [s] (first-order thermal model)."""
        if self.current is None or self.coldest is None or not (math.isfinite(seconds) and seconds > 0):
            return
        self.current = self.coldest + (self.current - self.coldest) * math.exp(-seconds / time_constant_s)

    def observe(self, temperature: float | None) -> None:
        """The lubricant temperature estimated from a closed cycle [°C]; the first one is the reference."""
        if temperature is None or not math.isfinite(temperature):
            return
        if self.current is None:
            self.current = float(temperature)
        else:
            self.current += self.smoothing * (float(temperature) - self.current)
        if self.reference is None:
            self.reference = self.current
        self.coldest = self.current if self.coldest is None else min(self.coldest, self.current)

    @property
    def shift(self) -> float:
        """ξc − ξref [°C] (0 until both are known)."""
        if self.reference is None or self.current is None:
            return 0.0
        return self.current - self.reference

    def apply(self, torque: NDArray[np.float64], speed: NDArray[np.float64]) -> NDArray[np.float64]:
        """``torque`` as it would be at the reference temperature."""
        if self.reference is None or self.current is None or self.current == self.reference:
            return torque
        a = np.abs(speed)
        change = nominal_friction(a, 0.0, self.current, self.params) - nominal_friction(a, 0.0, self.reference,
                                                                                         self.params)
        return torque - np.sign(speed) * change

    def reset(self) -> None:
        """Relearn the reference (declared maintenance: the nominal density is relearned too)."""
        self.reference = None

    def state_dict(self) -> dict[str, Any]:
        return {"reference": self.reference, "current": self.current, "coldest": self.coldest}

    def load_state(self, state: dict[str, Any]) -> None:
        for key in ("reference", "current", "coldest"):
            value = state.get(key)
            setattr(self, key, float(value) if isinstance(value, (int, float)) and math.isfinite(value) else None)
