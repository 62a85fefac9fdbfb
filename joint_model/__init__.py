"""The physics shared by the simulator (ground truth) and the agent (its model of a joint).

Friction of a robot joint as a function of motor speed, load torque, lubricant temperature and gearbox
wear (docs/ALGORITHMS.md §1), its parameters, and the constants of the wear scale.
"""

from joint_model.friction import (
    CRITICAL_WEAR,
    DEFAULT_PARAMS,
    DEFAULT_SPEED_LEVELS,
    FRICTION_NOISE_STD,
    WEAR_MAX,
    FrictionParams,
    friction,
    friction_magnitude,
    jacobian_temperature_wear,
    load_sensitivity,
    nominal_friction,
    speed_only_friction,
    stribeck_speed,
    wear_friction,
)

__all__ = [
    "CRITICAL_WEAR", "DEFAULT_PARAMS", "DEFAULT_SPEED_LEVELS", "FRICTION_NOISE_STD", "WEAR_MAX", "FrictionParams",
    "friction", "friction_magnitude", "jacobian_temperature_wear", "load_sensitivity", "nominal_friction",
    "speed_only_friction", "stribeck_speed", "wear_friction",
]
