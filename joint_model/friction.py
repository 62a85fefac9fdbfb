"""Steady-state friction model of a robot joint (docs/ALGORITHMS.md §1).

Units: motor speed ``v`` in rad/s (motor side), torques dimensionless (fraction of the
joint's maximum torque), load torque ``load`` dimensionless, lubricant temperature ``temperature``
in °C, wear level ``wear`` dimensionless on 0 … 100 (35 = critical).

Friction is direction independent: ``friction(-v) == -friction(v)``. All functions broadcast
over numpy arrays. The same implementation is the simulator's ground truth and the agent's model, which is why it
lives in ``joint_model`` and not in either of them.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, fields
from typing import Mapping

import numpy as np
from numpy.typing import ArrayLike, NDArray

#: Critical wear level to alarm on (docs/ALGORITHMS.md, units).
CRITICAL_WEAR = 35.0
#: Top of the wear scale: 100 = failure.
WEAR_MAX = 100.0
#: Default friction speed levels of the repetitive test cycle [rad/s] (docs/ALGORITHMS.md §2).
DEFAULT_SPEED_LEVELS: tuple[float, ...] = (2.1, 8.7, 15.3, 21.9, 28.5, 35.1, 41.7, 82.2, 133.5, 184.7, 236.2, 287.1)
#: Combined prediction error of a friction datum (std), used as measurement noise.
FRICTION_NOISE_STD = 5.70e-3
#: Smallest Stribeck speed used in evaluation [rad/s]. ``vs0 + vsξ·ξ`` is negative below
#: ≈ 25.3 °C for the default joint; clipping it makes the temperature Stribeck term vanish
#: continuously there instead of producing NaN. The model is identified on 35 … 80 °C.
_MIN_STRIBECK_SPEED = 1e-9


@dataclass(frozen=True)
class FrictionParams:
    """Parameters of ``τf(v, τl, ξ, ϖ) = τ0(v, τl, ξ) + τw(v, ϖ)`` (names as in docs/ALGORITHMS.md §1)."""

    fc0: float = 3.11e-2
    fcl: float = 2.34e-2
    fs0: float = -2.50e-2
    fsl: float = 1.26e-1
    fsxi: float = 1.60e-3
    fv0: float = 1.30e-4
    fvxi: float = 1.32e-3
    vs0: float = -24.81
    vsl: float = 9.22
    vsxi: float = 0.98
    xi_vo: float = 20.71
    alpha: float = 1.36
    fsw: float = 9.02e-4
    fvw: float = -5.15e-7
    vsw: float = 2.19

    def to_dict(self) -> dict[str, float]:
        return asdict(self)

    @classmethod
    def from_mapping(cls, values: Mapping[str, object], where: str = "friction") -> "FrictionParams":
        """Build from a config mapping; unknown, non-numeric or out-of-range fields raise ``ValueError``
        naming the field. Missing fields take the default (§1 table) value."""
        known = {f.name for f in fields(cls)}
        unknown = sorted(set(values) - known)
        if unknown:
            raise ValueError(f"{where}: unknown parameter(s) {unknown}; known: {sorted(known)}")
        parsed: dict[str, float] = {}
        for name, raw in values.items():
            try:
                value = float(raw)  # type: ignore[arg-type]
            except (TypeError, ValueError):
                raise ValueError(f"{where}.{name}: expected a number, got {raw!r}") from None
            if not math.isfinite(value):
                raise ValueError(f"{where}.{name}: must be finite, got {raw!r}")
            parsed[name] = value
        params = cls(**parsed)
        for name in ("vsl", "xi_vo", "alpha", "vsw"):
            if getattr(params, name) <= 0:
                raise ValueError(f"{where}.{name}: must be > 0, got {getattr(params, name)}")
        return params


DEFAULT_PARAMS = FrictionParams()


def _abs_speed(v: ArrayLike) -> NDArray[np.float64]:
    return np.abs(np.asarray(v, dtype=float))


def stribeck_speed(temperature: ArrayLike, p: FrictionParams = DEFAULT_PARAMS) -> NDArray[np.float64]:
    """Temperature-dependent Stribeck speed ``vs0 + vsξ·ξ`` [rad/s], clipped to stay positive."""
    return np.maximum(p.vs0 + p.vsxi * np.asarray(temperature, dtype=float), _MIN_STRIBECK_SPEED)


def load_sensitivity(v: ArrayLike, p: FrictionParams = DEFAULT_PARAMS) -> NDArray[np.float64]:
    """``s(v) = ∂τf/∂|τl| = fcl + fsl·exp(−(|v|/vsl)^α)`` (the model is linear in |τl|)."""
    a = _abs_speed(v)
    return p.fcl + p.fsl * np.exp(-((a / p.vsl) ** p.alpha))


def nominal_friction(v: ArrayLike, load: ArrayLike, temperature: ArrayLike,
                     p: FrictionParams = DEFAULT_PARAMS) -> NDArray[np.float64]:
    """Nominal friction ``τ0`` for ``|v|`` (magnitude, ≥ 0) at load ``load`` and temperature [°C]."""
    a = _abs_speed(v)
    xi = np.asarray(temperature, dtype=float)
    abs_load = np.abs(np.asarray(load, dtype=float))
    vs = stribeck_speed(xi, p)
    return ((p.fc0 + p.fcl * abs_load)
            + p.fsl * abs_load * np.exp(-((a / p.vsl) ** p.alpha))
            + (p.fs0 + p.fsxi * xi) * np.exp(-((a / vs) ** p.alpha))
            + (p.fv0 + p.fvxi * np.exp(-xi / p.xi_vo)) * a)


def _wear_exponent(a: NDArray[np.float64], wear: NDArray[np.float64], p: FrictionParams) -> NDArray[np.float64]:
    """``u = (|v| / (ϖ·vsϖ))^α``; +inf where ϖ = 0 (the wear Stribeck term vanishes there)."""
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        u = (a / (np.maximum(wear, 0.0) * p.vsw)) ** p.alpha
    return np.where(wear > 0, u, np.inf)


def wear_friction(v: ArrayLike, wear: ArrayLike, p: FrictionParams = DEFAULT_PARAMS) -> NDArray[np.float64]:
    """Wear part ``τw = fsϖ·ϖ·exp(−(|v|/(ϖ·vsϖ))^α) + fvϖ·ϖ·|v|``."""
    a = _abs_speed(v)
    w = np.asarray(wear, dtype=float)
    u = _wear_exponent(a, w, p)
    return p.fsw * w * np.exp(-u) + p.fvw * w * a


def friction(v: ArrayLike, load: ArrayLike, temperature: ArrayLike, wear: ArrayLike = 0.0,
             p: FrictionParams = DEFAULT_PARAMS) -> NDArray[np.float64]:
    """Complete signed friction ``τf(v, τl, ξ, ϖ)``; odd in ``v`` (zero at ``v = 0``)."""
    sign = np.sign(np.asarray(v, dtype=float))
    return sign * (nominal_friction(v, load, temperature, p) + wear_friction(v, wear, p))


def friction_magnitude(v: ArrayLike, load: ArrayLike, temperature: ArrayLike, wear: ArrayLike = 0.0,
                       p: FrictionParams = DEFAULT_PARAMS) -> NDArray[np.float64]:
    """``τf(|v|, …)``: the friction datum a back-and-forth experiment measures, ``(τ⁺ − τ⁻)/2``."""
    return nominal_friction(v, load, temperature, p) + wear_friction(v, wear, p)


def jacobian_temperature_wear(v: ArrayLike, temperature: float, wear: float,
                              p: FrictionParams = DEFAULT_PARAMS) -> NDArray[np.float64]:
    """``J = ∂τf(|v|)/∂[ξ, ϖ]`` as an (N, 2) array (analytic; load does not enter)."""
    a = _abs_speed(v).reshape(-1)
    xi = float(temperature)
    vs = float(stribeck_speed(xi, p))
    w_t = (a / vs) ** p.alpha
    e_t = np.exp(-w_t)
    d_vs = p.vsxi if p.vs0 + p.vsxi * xi > _MIN_STRIBECK_SPEED else 0.0
    d_xi = (p.fsxi * e_t
            + (p.fs0 + p.fsxi * xi) * e_t * p.alpha * w_t * d_vs / vs
            - p.fvxi / p.xi_vo * math.exp(-xi / p.xi_vo) * a)
    wear_arr = np.full_like(a, max(float(wear), 0.0))
    u = _wear_exponent(a, wear_arr, p)
    with np.errstate(invalid="ignore"):
        stribeck = np.where(np.isfinite(u), np.exp(-u) * (1.0 + p.alpha * u), 0.0)
    d_wear = p.fsw * stribeck + p.fvw * a
    return np.column_stack([d_xi, d_wear])


def speed_only_friction(v: ArrayLike, fc: float = 3.4e-2, fs: float = 4.6e-2, vs: float = 10.68,
                        fv: float = 3.68e-4, alpha: float = 1.93) -> NDArray[np.float64]:
    """Speed-only baseline model ``fc + fs·exp(−(|v|/vs)^α) + fv·|v|`` (signed, odd in ``v``)."""
    arr = np.asarray(v, dtype=float)
    a = np.abs(arr)
    return np.sign(arr) * (fc + fs * np.exp(-((a / vs) ** alpha)) + fv * a)
