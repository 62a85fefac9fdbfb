"""Torque samples moved to a reference lubricant temperature with the joint's friction model.

Temperature changes friction as much as critical wear does (docs/studies/DISTURBANCE_STUDY.md): at low
speed friction rises with ξ, at high speed the viscous slope falls. A distribution-domain detector
that compares each cycle's torque density with a nominal one learned at the start of a shift sees
that as a change. The friction model knows how friction depends on ξ, so each sample is moved to the
reference temperature ξref (the joint's temperature when its nominal density was learned):

    τ ← τ − sign(v)·[τ0(|v|, ξc) − τ0(|v|, ξref)]

with ξc the joint's current lubricant temperature, estimated from the friction data of the previous
cycles (the wear feature's ξ̂, smoothed exponentially: the lubricant moves ≲ 0.1 °C per cycle). Where the
controller sends no motor temperature, ξ̂ is looser and wear moves it; there ξc is the joint's thermal model
driven by its dissipated power, corrected by ξ̂ (:mod:`edge_monitor.features.lubricant_thermal_filter`), when the
cycle's power is known, else ξ̂ smoothed with :data:`LOOSE_SMOOTHING`. The load terms of τ0 do not depend on ξ
and cancel; wear is not touched.

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

from edge_monitor.features.lubricant_thermal_filter import (
    LubricantThermalFilter,
    ThermalFilterConfig,
    ThermalObservation,
)
from joint_model import FrictionParams, nominal_friction

#: The weight of a cycle's ξ̂ estimated without a motor temperature, where the cycle's power is unknown: with a flat
#: prior over the site range it scatters ±3–6 °C and runs 5–7 °C off for a dozen cycles at a time, and the KL
#: distances follow the over-correction (docs/WITHOUT_MOTOR_TEMPERATURE.md). On the 20 such robots it was
#: chosen on, at one false alarm per robot-week, the warm-up stage delivered 3.1× its rate with 0.2,
#: 0.99× with 0.1 and 0.85× with 0.05 (on 20 held-out robots 2.1× with 0.1); a medium wear ramp was found 3–17
#: cycles after the same robot with a motor temperature with 0.1, 2–12 with 0.2, 3–22 with 0.05.
LOOSE_SMOOTHING = 0.1


class TemperatureCompensation:
    """See the module docstring. ``smoothing``: weight of the newest cycle's ξ̂ in the running estimate
    (``loose_smoothing`` for a ξ̂ estimated without a motor temperature)."""

    def __init__(self, params: FrictionParams, smoothing: float = 0.2,
                 loose_smoothing: float = LOOSE_SMOOTHING, time_constant_s: float = 3.04 * 3600.0) -> None:
        self.params = params
        self.smoothing = float(smoothing)
        self.loose_smoothing = float(loose_smoothing)
        self.thermal = LubricantThermalFilter(ThermalFilterConfig(time_constant_s=float(time_constant_s)))
        self.follows_thermal = False               # whether ξc is the thermal model's (the last cycle's was)
        self.reference: float | None = None
        self.current: float | None = None
        self.coldest: float | None = None          # lowest smoothed ξ so far: the idle temperature a pause cools to

    def cool(self, seconds: float) -> None:
        """The joint stood still for ``seconds``: its lubricant cooled (the thermal model's own cooling where ξc
        follows it, else towards :attr:`coldest` with the thermal model's time constant)."""
        if self.current is None or self.coldest is None or not (math.isfinite(seconds) and seconds > 0):
            return
        if self.follows_thermal:
            self.current = self.thermal.cool(seconds)
            return
        decay = math.exp(-seconds / self.thermal.config.time_constant_s)
        self.current = self.coldest + (self.current - self.coldest) * decay

    def observe(self, temperature: float | None, loose: bool = False,
                heating: tuple[float, float] | None = None) -> None:
        """The lubricant temperature estimated from a closed cycle [°C] (``loose``: without a motor temperature;
        ``heating``: the seconds since the previous cycle and the mean power over them, for the thermal model);
        the first one is the reference."""
        self.follows_thermal = loose and heating is not None
        if loose and heating is not None:
            estimate = self.thermal.update(ThermalObservation(heating[0], heating[1], temperature))
            if estimate is None:
                return
            self.current = estimate
        elif temperature is None or not math.isfinite(temperature):
            return
        elif self.current is None:
            self.current = float(temperature)
        else:
            weight = self.loose_smoothing if loose else self.smoothing
            self.current += weight * (float(temperature) - self.current)
        if self.reference is None:
            self.reference = self.current
        self.coldest = self.current if self.coldest is None else min(self.coldest, self.current)

    def section(self) -> dict[str, Any]:
        """For the symptom's ``kl.temperature``: ξc and ξref [°C], and what ξc follows."""
        return {"value": self.current, "reference": self.reference,
                "source": "thermal_model" if self.follows_thermal else "smoothed"}

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
        """Relearn the reference (declared maintenance: the nominal density is relearned too, and the new
        lubricant's thermal model)."""
        self.reference = None
        self.thermal.reset()

    def state_dict(self) -> dict[str, Any]:
        return {"reference": self.reference, "current": self.current, "coldest": self.coldest,
                "thermal": self.thermal.state_dict(), "follows_thermal": self.follows_thermal}

    def load_state(self, state: dict[str, Any]) -> None:
        for key in ("reference", "current", "coldest"):
            value = state.get(key)
            setattr(self, key, float(value) if isinstance(value, (int, float)) and math.isfinite(value) else None)
        self.thermal = LubricantThermalFilter.from_state(state.get("thermal"), self.thermal.config)
        self.follows_thermal = state.get("follows_thermal") is True and self.thermal.temperature is not None
