"""First-order lubricant thermal model (docs/ALGORITHMS.md §1, "Thermal behaviour").

``τth·dξ/dt = ξamb + K·P − ξ`` with time constant τth (default 3.04 h), ambient ξamb [°C], heating
gain K [°C per unit friction power, power = |τf·v| in (torque fraction)·rad/s] and the joint's mean
friction power P. A time-acceleration factor A makes simulated hours pass in seconds: the model
advances by A·dt for each dt of controller time. The update is the exact solution for P constant
over the step, so the step response is an exact exponential with time constant τth / A.
"""

from __future__ import annotations

import math
from dataclasses import dataclass


@dataclass
class ThermalModel:
    """Lubricant temperature ξ [°C] of one joint."""

    temperature: float = 30.0
    ambient: float = 30.0
    time_constant: float = 3.04 * 3600.0   # [s]
    heating: float = 4.0                    # [°C per unit power]
    time_acceleration: float = 1.0

    def steady_state(self, power: float) -> float:
        """Temperature the model tends to under constant friction power [°C]."""
        return self.ambient + self.heating * power

    def advance(self, dt: float, power: float) -> float:
        """Advance by ``dt`` seconds of controller time at mean friction power ``power``; return ξ."""
        decay = math.exp(-self.time_acceleration * dt / self.time_constant)
        target = self.steady_state(power)
        self.temperature = target + (self.temperature - target) * decay
        return self.temperature
