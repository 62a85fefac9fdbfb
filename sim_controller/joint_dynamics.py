"""Motor-side rigid joint with a PI + feed-forward speed controller, gravity and friction.

Plant: ``J·ω̇ = u − τf(ω) − τg``. Controller: ``u = J·a_ref + τ̂g + Kp·ε + Ki·∫ε`` with the
tracking error ``ε = ω_ref − ω`` and τ̂g the controller's gravity model (its load estimate). With
``x = ∫ε`` the error obeys the linear system

    J·ẍ + Kp·ẋ + Ki·x = d,      d = τf(ω) + (τg − τ̂g)

so the PI output is ``p = Kp·ε + Ki·x`` and the torque signal ``u = J·a_ref + τ̂g + p``; at a
constant speed ε → 0 and ``u = τg + τf`` exactly (docs/ALGORITHMS.md §2).

Integration (the choice the issue asks to document): the linear part is discretised exactly
(zero-order hold on d over a controller tick, ``scipy.signal.cont2discrete``) and run over a whole
block with ``scipy.signal.lfilter`` (state carried between blocks). The friction nonlinearity
closes the loop through ``ω = ω_ref − ε``; it is resolved by a fixed-point (Picard) iteration over
the block: d is evaluated at ω_ref, filtered, re-evaluated at the resulting ω, and so on. The map
is strictly causal and its loop gain is |∂τf/∂v|/Kp ≲ 0.3, so three iterations leave errors far
below the measurement noise; on constant-speed plateaus the result is exact.

Units: torque dimensionless (fraction of max joint torque), speed rad/s, angle rad, inertia in
torque·s²/rad, Kp in torque·s/rad, Ki in torque/rad.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

import numpy as np
from numpy.typing import NDArray
from scipy import signal

#: Fixed-point iterations for the friction feedback (see module docstring).
PICARD_ITERATIONS = 3


@dataclass(frozen=True)
class SpeedLoopParams:
    """Motor-side inertia and PI gains, from a closed-loop natural frequency ω_n and damping ζ."""

    inertia: float = 1.0e-4        # J [torque·s²/rad]
    bandwidth: float = 150.0       # ω_n [rad/s]
    damping: float = 1.0           # ζ

    @property
    def kp(self) -> float:
        return 2.0 * self.damping * self.bandwidth * self.inertia

    @property
    def ki(self) -> float:
        return self.bandwidth**2 * self.inertia


class SpeedLoop:
    """Exactly discretised error dynamics of the PI speed loop for several joints at once."""

    def __init__(self, params: SpeedLoopParams, rate: float, joints: int) -> None:
        self.params = params
        j, kp, ki = params.inertia, params.kp, params.ki
        a = np.array([[0.0, 1.0], [-ki / j, -kp / j]])
        b = np.array([[0.0], [1.0 / j]])
        c = np.eye(2)                       # outputs x = ∫ε and ε
        ad, bd, cd, dd, _ = signal.cont2discrete((a, b, c, np.zeros((2, 1))), 1.0 / rate, method="zoh")
        num, den = signal.ss2tf(ad, bd, cd, dd)
        self._b_x, self._b_eps = num[0], num[1]
        self._a = den
        self._zi_x = np.zeros((joints, 2))
        self._zi_eps = np.zeros((joints, 2))

    def reset(self) -> None:
        self._zi_x[:] = 0.0
        self._zi_eps[:] = 0.0

    def respond(self, d: NDArray[np.float64], commit: bool) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """Error integral x and error ε for the disturbance ``d`` (joints × n); ``commit`` keeps the state."""
        x, zx = signal.lfilter(self._b_x, self._a, d, axis=-1, zi=self._zi_x)
        eps, ze = signal.lfilter(self._b_eps, self._a, d, axis=-1, zi=self._zi_eps)
        if commit:
            self._zi_x, self._zi_eps = zx, ze
        return x, eps


@dataclass(frozen=True)
class JointResponse:
    """Simulated signals of one block (joints × n)."""

    torque: NDArray[np.float64]     # controller torque signal u (noise-free)
    speed: NDArray[np.float64]      # actual motor speed ω [rad/s]
    angle_error: NDArray[np.float64]   # x = ∫ε [rad]; actual angle = reference angle − x
    friction: NDArray[np.float64]   # friction torque applied (signed)


#: ``friction_fn(speed, mask, previous)``: signed friction at ``speed`` (joints × n); with a mask, only
#: the masked entries are recomputed and the others are taken from ``previous``.
FrictionFn = Callable[[NDArray[np.float64], NDArray[np.bool_] | None, NDArray[np.float64] | None],
                      NDArray[np.float64]]
#: A fixed-point iteration re-evaluates friction only where the speed moved by more than this
#: [rad/s]; |∂τf/∂v| < 0.02 s/rad, so the skipped change is < 2e-8, far below the 5e-5 torque LSB.
FRICTION_SPEED_TOLERANCE = 1e-6


def simulate_block(loop: SpeedLoop, ref_speed: NDArray[np.float64], ref_accel: NDArray[np.float64],
                   gravity: NDArray[np.float64], gravity_ff: NDArray[np.float64],
                   friction_fn: FrictionFn, iterations: int = PICARD_ITERATIONS) -> JointResponse:
    """Run the closed loop over one block.

    ``ref_speed``/``ref_accel`` (n,) are shared by all joints; ``gravity`` (true τg) and
    ``gravity_ff`` (controller model τ̂g) are (joints × n); ``friction_fn`` maps the
    (joints × n) speed to the signed friction torque (see :data:`FrictionFn`).
    """
    speed = np.array(np.broadcast_to(ref_speed, gravity.shape))   # speed friction is evaluated at
    mismatch = gravity - gravity_ff
    friction = friction_fn(speed, None, None)
    for _ in range(iterations - 1):
        _, eps = loop.respond(friction + mismatch, commit=False)
        moved = np.abs(ref_speed - eps - speed) > FRICTION_SPEED_TOLERANCE
        if not moved.any():
            break
        speed[moved] = (ref_speed - eps)[moved]
        friction = friction_fn(speed, moved, friction)
    x, eps = loop.respond(friction + mismatch, commit=True)
    p = loop.params.ki * x + loop.params.kp * eps
    torque = loop.params.inertia * ref_accel + gravity_ff + p
    return JointResponse(torque=torque, speed=ref_speed - eps, angle_error=x, friction=friction)
