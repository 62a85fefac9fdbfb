"""Simple baseline detectors for comparisons (docs/ALGORITHMS.md §7), computed from what the agent
extracted per cycle: its friction curve (speeds rad/s, friction torque dimensionless) and the KL
feature's torque densities (the cycle's and the nominal one, on the same uniform grid).

* **Parameter change** — the speed-only model ``τf = fc + fs·exp(−(v/vs)^α) + fv·v`` fitted per cycle,
  compared with its nominal parameters: ``χ² = (θ̂ − θ0)ᵀ Σθ⁻¹ (θ̂ − θ0)``. With Σθ and θ0 estimated from
  n nominal cycles this is Hotelling's T², not χ²: when healthy it follows
  ``p(n+1)(n−1)/(n(n−p))·F(p, n−p)`` (p = 3), which tends to χ²₃ only for many nominal cycles.
  Choices (the spec leaves them open): α fixed at 1.36 (the best single value over many curves)
  and vs fixed at its nominal value (found by variable projection on the pooled nominal curves), so
  θ = [fc, fs, fv] enters linearly and each cycle's fit is ordinary least squares on ~12 data;
  θ0 and Σθ are the mean and covariance of the nominal cycles' θ̂ (cycle-to-cycle spread, which
  includes load and model-error variation, not only the least-squares covariance).
* **Distribution peak** — ``q = 1 − 1/(√(2π)·σ̂)``, σ̂ the standard deviation of the cycle's density
  (the peak of a normal density of that spread).
* **Data likelihood** — ``q = −(1/N)·Σ log p̂0(yn)``, the mean negative log nominal density of the
  cycle's samples, here ``−∫ p_k log p̂0 dy`` with the cycle's binned density p_k; mass of the cycle
  outside the grid counts at the floor of p̂0 (never dropped).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Sequence

import numpy as np
from numpy.typing import ArrayLike, NDArray

from edge_monitor.stats.kde_stream import DEFAULT_RELATIVE_FLOOR

#: Stribeck exponent of the speed-only model (fixed).
SPEED_ONLY_ALPHA = 1.36
#: Stribeck speeds tried for the nominal fit [rad/s].
VS_GRID = np.geomspace(2.0, 60.0, 120)
#: Ridge added to Σθ relative to its diagonal (three parameters from a few tens of nominal cycles).
COV_RIDGE = 1e-6


class BaselineError(ValueError):
    """Too little or unusable nominal data for a baseline."""


def speed_only_regressors(speeds: ArrayLike, vs: float, alpha: float = SPEED_ONLY_ALPHA) -> NDArray[np.float64]:
    """Columns [1, exp(−(|v|/vs)^α), |v|] of the speed-only model (N × 3)."""
    a = np.abs(np.asarray(speeds, dtype=float))
    return np.column_stack([np.ones_like(a), np.exp(-((a / vs) ** alpha)), a])


def speed_only_parameters(speeds: ArrayLike, friction: ArrayLike, vs: float,
                          alpha: float = SPEED_ONLY_ALPHA) -> NDArray[np.float64]:
    """Least-squares θ̂ = [fc, fs, fv] of one friction curve (NaN when it has fewer than 3 points)."""
    v, tau = np.asarray(speeds, dtype=float), np.asarray(friction, dtype=float)
    keep = np.isfinite(v) & np.isfinite(tau)
    if keep.sum() < 3:
        return np.full(3, math.nan)
    theta, *_ = np.linalg.lstsq(speed_only_regressors(v[keep], vs, alpha), tau[keep], rcond=None)
    return theta


@dataclass(frozen=True)
class SpeedOnlyNominal:
    """Nominal speed-only model: vs [rad/s], α, θ0 = [fc, fs, fv] and the covariance Σθ of per-cycle θ̂."""

    vs: float
    alpha: float
    theta0: NDArray[np.float64]
    cov: NDArray[np.float64]

    def chi2(self, speeds: ArrayLike, friction: ArrayLike) -> float:
        """``(θ̂ − θ0)ᵀ Σθ⁻¹ (θ̂ − θ0)`` of one cycle's curve (NaN when it cannot be fitted)."""
        d = speed_only_parameters(speeds, friction, self.vs, self.alpha) - self.theta0
        if not np.all(np.isfinite(d)):
            return math.nan
        return float(d @ np.linalg.solve(self.cov, d))

    def standardised(self, speeds: ArrayLike, friction: ArrayLike) -> NDArray[np.float64]:
        """Per parameter ``(θ̂i − θ0i)/√[Σθ]ii`` (≈ N(0, 1) when healthy)."""
        d = speed_only_parameters(speeds, friction, self.vs, self.alpha) - self.theta0
        return d / np.sqrt(np.diag(self.cov))


def fit_speed_only_nominal(curves: Sequence[tuple[ArrayLike, ArrayLike]],
                           alpha: float = SPEED_ONLY_ALPHA) -> SpeedOnlyNominal:
    """The nominal model from nominal friction curves ``[(speeds, friction), ...]`` (at least 4 curves
    of ≥ 3 points): vs by variable projection on the pooled data, then θ̂ per curve."""
    arrays = [(np.asarray(v, dtype=float), np.asarray(t, dtype=float)) for v, t in curves]
    usable = [(v, t) for v, t in arrays if v.size >= 3 and v.shape == t.shape]
    if len(usable) < 4:
        raise BaselineError(f"parameter change: need ≥ 4 nominal friction curves of ≥ 3 points, got {len(usable)}")
    v = np.concatenate([c[0] for c in usable])
    tau = np.concatenate([c[1] for c in usable])
    residuals = []
    for vs in VS_GRID:
        phi = speed_only_regressors(v, float(vs), alpha)
        theta, *_ = np.linalg.lstsq(phi, tau, rcond=None)
        residuals.append(float(np.sum((tau - phi @ theta) ** 2)))
    vs = float(VS_GRID[int(np.argmin(residuals))])
    thetas = np.array([speed_only_parameters(sv, st, vs, alpha) for sv, st in usable])
    thetas = thetas[np.all(np.isfinite(thetas), axis=1)]
    if len(thetas) < 2:
        raise BaselineError(f"parameter change: only {len(thetas)} of {len(usable)} nominal friction curves could be "
                            "fitted (need ≥ 2 for the nominal covariance)")
    cov = np.atleast_2d(np.cov(thetas, rowvar=False))
    cov = cov + COV_RIDGE * np.diag(np.maximum(np.diag(cov), 1e-30))
    return SpeedOnlyNominal(vs=vs, alpha=alpha, theta0=thetas.mean(axis=0), cov=cov)


def _moments(grid: NDArray[np.float64], density: NDArray[np.float64]) -> tuple[float, float, float]:
    dx = float(grid[1] - grid[0])
    mass = float(np.sum(density) * dx)
    if not mass > 0:                                  # no density on the grid: no moments
        return mass, math.nan, math.nan
    mean = float(np.sum(grid * density) * dx / mass)
    var = float(np.sum((grid - mean) ** 2 * density) * dx / mass)
    return mass, mean, var


def distribution_peak(grid: ArrayLike, density: ArrayLike) -> float:
    """``1 − 1/(√(2π)·σ̂)`` with σ̂ the standard deviation of ``density`` on the uniform ``grid``."""
    g, p = np.asarray(grid, dtype=float), np.asarray(density, dtype=float)
    mass, _, var = _moments(g, p)
    if not (mass > 0 and var > 0):
        return math.nan
    return 1.0 - 1.0 / (math.sqrt(2.0 * math.pi) * math.sqrt(var))


def data_likelihood(grid: ArrayLike, density: ArrayLike, nominal: ArrayLike, floor: float | None = None) -> float:
    """``−∫ p·log max(p0, ε) dy`` on the uniform ``grid`` plus the mass of ``density`` missing from the
    grid times ``−log ε``; ``ε = floor`` or :data:`DEFAULT_RELATIVE_FLOOR` × max p0 (as the KL distance)."""
    g, p, p0 = (np.asarray(a, dtype=float) for a in (grid, density, nominal))
    if p.shape != g.shape or p0.shape != g.shape:
        raise ValueError(f"data_likelihood: grid, density and nominal differ in shape: {g.shape}, {p.shape}, "
                         f"{p0.shape}")
    dx = float(g[1] - g[0])
    eps = DEFAULT_RELATIVE_FLOOR * float(p0.max(initial=0.0)) if floor is None else float(floor)
    if not eps > 0:
        return math.nan
    log_p0 = np.log(np.maximum(p0, eps))
    inside = float(np.sum(p) * dx)
    return float(-np.sum(p * log_p0) * dx - max(0.0, 1.0 - inside) * math.log(eps))
