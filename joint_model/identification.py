"""Identification of a joint's nominal friction model from nominal friction data (docs/ALGORITHMS.md §1).

Data: friction data (dimensionless) at speeds ``|v|`` [rad/s] with known lubricant temperature [°C]
and load torque ``τl`` (dimensionless), all at wear ϖ = 0 (a new or nominal joint).

The nominal model is linear in η = (fc0, fcl, fsl, fs0, fsξ, fv0, fvξ) for fixed nonlinear
ρ = (vsl, vs0, vsξ, ξVo). Variable projection: for a given ρ, η̂(ρ) is ordinary least squares on
the regressor matrix Φ(ρ); ρ̂ minimises the projected residual ``‖(I − ΦΦ⁺)τ‖²`` with a bounded
``least_squares`` (finite-difference Jacobian of the projected residual), started from the best
point of a coarse 4-D grid. The columns of Φ are :func:`joint_model.friction.nominal_friction`
evaluated with unit η (the model is linear in η), so no formula is duplicated here.
:func:`identify_linear` identifies a subset of η with everything else fixed (plain least squares:
what little data can tell, e.g. during an agent's learning phase).

Fixed, not identified: α, and the wear parameters fsϖ, fvϖ, vsϖ, which nominal (ϖ = 0) data cannot
show; they are copied from the base parameters.

Covariance of the estimated parameters: ``Σ̂ = γ̂·(Σk ψk ψkᵀ)⁻¹``, ``γ̂ = (1/N)·Σ ε²``, ψ the
gradient of the prediction w.r.t. the estimated parameters (η columns exact, ρ columns by central
differences). The offline command around it is ``edge-monitor commission``.
"""

from __future__ import annotations

import itertools
import math
from dataclasses import dataclass, replace

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.optimize import least_squares

from joint_model.friction import DEFAULT_PARAMS, FrictionParams, nominal_friction

LINEAR_NAMES: tuple[str, ...] = ("fc0", "fcl", "fsl", "fs0", "fsxi", "fv0", "fvxi")
NONLINEAR_NAMES: tuple[str, ...] = ("vsl", "vs0", "vsxi", "xi_vo")
#: The data an identification needs, one value per datum.
DATA_COLUMNS: tuple[str, ...] = ("speed", "temperature", "load", "friction")

#: Bounds of ρ = (vsl, vs0, vsξ, ξVo) for the solver [rad/s, rad/s, rad/s/°C, °C].
NONLINEAR_LOWER = np.array([0.5, -100.0, 0.0, 2.0])
NONLINEAR_UPPER = np.array([100.0, 100.0, 5.0, 500.0])
#: Coarse start grid of ρ (4-D, 5 × 7 × 6 × 6 points).
_START_GRID = (np.array([3.0, 6.0, 10.0, 20.0, 40.0]),
               np.array([-60.0, -40.0, -25.0, -10.0, 0.0, 10.0, 30.0]),
               np.array([0.1, 0.4, 0.8, 1.2, 2.0, 3.0]),
               np.array([5.0, 10.0, 20.0, 40.0, 80.0, 200.0]))


class IdentificationDataError(ValueError):
    """Identification input that cannot be used (message names the column/row and the fix)."""


@dataclass(frozen=True)
class CommissioningData:
    """Nominal friction data: speeds |v| [rad/s], temperature [°C], load τl, friction τf (1-D, same length)."""

    speed: NDArray[np.float64]
    temperature: NDArray[np.float64]
    load: NDArray[np.float64]
    friction: NDArray[np.float64]

    @property
    def n(self) -> int:
        return int(self.friction.size)


@dataclass(frozen=True)
class CommissioningResult:
    """Identified parameters, their covariance (order ``names``) and fit statistics."""

    params: FrictionParams
    names: tuple[str, ...]
    covariance: NDArray[np.float64]
    noise_variance: float
    n_points: int
    rms_residual: float

    @property
    def std_errors(self) -> dict[str, float]:
        return {name: float(math.sqrt(max(self.covariance[i, i], 0.0))) for i, name in enumerate(self.names)}

    def report(self) -> dict:
        """JSON report: estimates, standard errors, covariance, γ̂, fixed parameters."""
        values = self.params.to_dict()
        return {"parameters": {name: values[name] for name in self.names},
                "std_errors": self.std_errors,
                "covariance": {"names": list(self.names), "matrix": self.covariance.tolist()},
                "noise_variance": self.noise_variance, "noise_std": math.sqrt(self.noise_variance),
                "rms_residual": self.rms_residual, "n_points": self.n_points,
                "fixed": {name: values[name] for name in values if name not in self.names}}

    def to_toml(self) -> str:
        """``[friction]`` config section (keys = FrictionParams field names) the agent reads."""
        lines = ["# Identified by `edge-monitor commission` (variable projection, docs/ALGORITHMS.md §1).",
                 "# alpha and the wear parameters fsw, fvw, vsw are fixed (not identifiable from nominal data).",
                 "[friction]"]
        lines += [f"{name} = {value!r}" for name, value in self.params.to_dict().items()]
        return "\n".join(lines) + "\n"


def make_data(speed: ArrayLike, temperature: ArrayLike, load: ArrayLike, friction: ArrayLike) -> CommissioningData:
    """Validate arrays into :class:`CommissioningData` (speeds as magnitudes, friction as |τf|)."""
    arrays = {name: np.asarray(value, dtype=float).reshape(-1)
              for name, value in zip(DATA_COLUMNS, (speed, temperature, load, friction))}
    sizes = {a.size for a in arrays.values()}
    if len(sizes) != 1:
        raise IdentificationDataError(f"columns {list(DATA_COLUMNS)} must have the same length")
    for name, values in arrays.items():
        if not np.all(np.isfinite(values)):
            raise IdentificationDataError(f"column '{name}': contains non-finite values; remove those rows")
    n_params = len(LINEAR_NAMES) + len(NONLINEAR_NAMES)
    if arrays["friction"].size <= n_params:
        raise IdentificationDataError(f"need more than {n_params} data rows, got {arrays['friction'].size}")
    if np.any(arrays["speed"] == 0):
        raise IdentificationDataError("column 'speed': zero speed carries no friction datum; remove those rows")
    for name in ("temperature", "load"):
        if np.ptp(arrays[name]) == 0:
            raise IdentificationDataError(f"column '{name}': no spread; the model needs data at several "
                                         f"{name} values to separate its {name} terms")
    return CommissioningData(speed=np.abs(arrays["speed"]), temperature=arrays["temperature"],
                             load=np.abs(arrays["load"]), friction=np.abs(arrays["friction"]))


def _with(base: FrictionParams, eta: ArrayLike, rho: ArrayLike) -> FrictionParams:
    values = dict(zip(LINEAR_NAMES, (float(x) for x in np.asarray(eta).reshape(-1))))
    values.update(zip(NONLINEAR_NAMES, (float(x) for x in np.asarray(rho).reshape(-1))))
    return replace(base, **values)


def regressors(data: CommissioningData, rho: ArrayLike, base: FrictionParams = DEFAULT_PARAMS) -> NDArray[np.float64]:
    """Φ(ρ) (N × 7): column j = nominal model with η = e_j (the model is linear in η)."""
    eye = np.eye(len(LINEAR_NAMES))
    return np.column_stack([nominal_friction(data.speed, data.load, data.temperature, _with(base, e, rho))
                            for e in eye])


def _linear_fit(data: CommissioningData, rho: ArrayLike, base: FrictionParams) -> tuple[NDArray, NDArray]:
    phi = regressors(data, rho, base)
    eta, *_ = np.linalg.lstsq(phi, data.friction, rcond=None)
    return eta, data.friction - phi @ eta


def projected_residual(data: CommissioningData, rho: ArrayLike, base: FrictionParams = DEFAULT_PARAMS) -> NDArray:
    """``(I − ΦΦ⁺)τ`` at ρ."""
    return _linear_fit(data, rho, base)[1]


def _grid_start(data: CommissioningData, base: FrictionParams) -> NDArray[np.float64]:
    best, best_cost = None, math.inf
    for rho in itertools.product(*_START_GRID):
        cost = float(np.sum(projected_residual(data, rho, base) ** 2))
        if cost < best_cost:
            best, best_cost = np.array(rho), cost
    if best is None:
        raise IdentificationDataError(f"no friction model fits these data (the residuals are not finite; the largest "
                                      f"|friction| is {float(np.max(np.abs(data.friction))):.3g}): is the friction "
                                      "column a joint's friction torque in N·m?")
    return np.asarray(best)


def identify(data: CommissioningData, base: FrictionParams = DEFAULT_PARAMS) -> CommissioningResult:
    """Variable-projection estimate of [η, ρ] with its covariance; α and wear parameters from ``base``."""
    rho0 = np.clip(_grid_start(data, base), NONLINEAR_LOWER, NONLINEAR_UPPER)
    fit = least_squares(lambda rho: projected_residual(data, rho, base), rho0,
                        bounds=(NONLINEAR_LOWER, NONLINEAR_UPPER), method="trf", jac="3-point",
                        x_scale="jac", xtol=1e-12, ftol=1e-14, gtol=1e-12, max_nfev=2000)
    rho = fit.x
    eta, resid = _linear_fit(data, rho, base)
    params = _with(base, eta, rho)
    names = LINEAR_NAMES + NONLINEAR_NAMES
    psi = prediction_gradient(data, params)
    gamma = float(np.mean(resid ** 2))
    covariance = np.asarray(gamma * np.linalg.pinv(psi.T @ psi), dtype=np.float64)
    return CommissioningResult(params=params, names=names, covariance=covariance, noise_variance=gamma,
                               n_points=data.n, rms_residual=math.sqrt(gamma))


def prediction_gradient(data: CommissioningData, params: FrictionParams) -> NDArray[np.float64]:
    """ψ (N × 11): ∂τ0/∂[η, ρ]; η columns exact (Φ), ρ columns by central differences."""
    rho = np.array([getattr(params, n) for n in NONLINEAR_NAMES])
    eta = np.array([getattr(params, n) for n in LINEAR_NAMES])
    columns = [regressors(data, rho, params)]
    for i in range(rho.size):
        step = 1e-6 * max(abs(rho[i]), 1.0)
        up, down = rho.copy(), rho.copy()
        up[i] += step
        down[i] -= step
        diff = (nominal_friction(data.speed, data.load, data.temperature, _with(params, eta, up))
                - nominal_friction(data.speed, data.load, data.temperature, _with(params, eta, down)))
        columns.append((diff / (2 * step))[:, None])
    return np.hstack(columns)


def identify_linear(data: CommissioningData, base: FrictionParams, free: tuple[str, ...],
                    prior_relative_std: float | None = None) -> CommissioningResult:
    """Estimate of the linear parameters ``free`` (a subset of :data:`LINEAR_NAMES`) with every other
    parameter fixed at ``base`` — the nonlinear ones included, so no search is needed.

    Without ``prior_relative_std``: least squares. With it: the maximum a posteriori estimate under a
    Gaussian prior centred on ``base`` with standard deviation ``prior_relative_std · |base|`` per
    parameter — ridge regression towards the base table (a base value of 0 stays 0), the noise variance
    taken from the least-squares residual — and the posterior covariance. For little data: the prior
    keeps what the data cannot tell at the base value instead of fitting noise (docs/ALGORITHMS.md §1)."""
    unknown = [name for name in free if name not in LINEAR_NAMES]
    if unknown or not free:
        raise IdentificationDataError(f"free parameters must be some of {LINEAR_NAMES}, got {list(free)}")
    rho = np.array([getattr(base, n) for n in NONLINEAR_NAMES])
    eta = np.array([getattr(base, n) for n in LINEAR_NAMES])
    phi = regressors(data, rho, base)
    columns = [LINEAR_NAMES.index(name) for name in free]
    fixed = [j for j in range(len(LINEAR_NAMES)) if j not in columns]
    target = data.friction - phi[:, fixed] @ eta[fixed]
    design = phi[:, columns]
    estimate, *_ = np.linalg.lstsq(design, target, rcond=None)
    gamma = float(np.mean((target - design @ estimate) ** 2))
    covariance: NDArray[np.float64]
    if prior_relative_std is None:
        covariance = np.asarray(gamma * np.linalg.pinv(design.T @ design), dtype=np.float64)
    else:
        prior_mean = eta[columns]
        prior_var = (prior_relative_std * prior_mean) ** 2
        keep = prior_var > 0                 # a base value of 0: a prior of zero width holds it at 0
        sub, precision = design[:, keep], np.diag(gamma / prior_var[keep])
        posterior = sub.T @ sub + precision
        estimate = np.zeros(len(columns))
        estimate[keep] = np.linalg.solve(posterior, sub.T @ target + precision @ prior_mean[keep])
        covariance = np.zeros((len(columns), len(columns)))
        covariance[np.ix_(keep, keep)] = gamma * np.linalg.pinv(posterior)
    eta[columns] = estimate
    rms = math.sqrt(float(np.mean((target - design @ estimate) ** 2)))
    return CommissioningResult(params=_with(base, eta, rho), names=tuple(free), covariance=covariance,
                               noise_variance=gamma, n_points=data.n, rms_residual=rms)
