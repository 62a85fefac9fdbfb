"""Which temperature a joint's detectors follow (their settling test, spans, slack and holds): the cycle's motor
temperature, or, on a joint whose controller never sent one (a foreign DBC without it), the lubricant temperature
the wear estimate reads from the friction curve with the joint's own model (docs/CONNECTING.md).

The two differ by the joint's motor-to-lubricant offset, so they never mix: a joint that has sent a motor
temperature has no temperature in a cycle without one, and the first motor temperature after friction-read ones
restarts the detectors' temperature history. Units: °C.
"""

from __future__ import annotations

from typing import Any

from edge_monitor.pipeline.detectors import SETTLING_KEY
from edge_monitor.pipeline.nominal_temperature import FRICTION_TEMPERATURE, MOTOR_TEMPERATURE


class TemperatureSource:
    """``pick(motor, lubricant) -> (temperature, what it is, restart)`` once per cycle (see the module docstring)."""

    def __init__(self, motor_seen: bool = False, friction_used: bool = False) -> None:
        self.motor_seen = motor_seen          # whether the controller ever sent this joint's motor temperature
        self.friction_used = friction_used    # whether the detectors followed the friction's temperature

    def pick(self, motor: float | None, lubricant: float | None) -> tuple[float | None, str, bool]:
        """This cycle's temperature [°C] from its motor temperature and the friction's lubricant temperature (None
        where unknown), what it is, and whether the detectors' temperature history must restart (the first motor
        temperature after friction-read ones)."""
        restart = False
        if motor is not None and not self.motor_seen:
            self.motor_seen, restart = True, self.friction_used
        if self.motor_seen:
            return motor, MOTOR_TEMPERATURE, restart
        self.friction_used |= lubricant is not None
        return lubricant, FRICTION_TEMPERATURE, False

    def state_dict(self) -> dict[str, Any]:
        return {"motor_temperature_seen": self.motor_seen, "friction_temperature_used": self.friction_used}

    @classmethod
    def from_joint_state(cls, state: dict[str, Any]) -> "TemperatureSource":
        """From a saved joint state; one saved before the sources were kept had its detectors follow the motor
        temperature alone: seen if its settling has values."""
        if "motor_temperature_seen" in state:
            return cls(state.get("motor_temperature_seen") is True, state.get("friction_temperature_used") is True)
        detectors = state.get("detectors")
        settling = detectors.get(SETTLING_KEY) if isinstance(detectors, dict) else None
        count = settling.get("count") if isinstance(settling, dict) else None
        return cls(isinstance(count, int) and not isinstance(count, bool) and count > 0, False)
