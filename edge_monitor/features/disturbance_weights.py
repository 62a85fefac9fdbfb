"""Disturbance-rejecting sample weights for the distribution-domain detector (docs/ALGORITHMS.md §4).

Each sample ``y`` is replaced by ``w·y`` to emphasise the parts of the data that react to wear
rather than to temperature. From labelled batches the per-index weights are
``w* ∝ diag(Σf + Σ0)⁻¹·(μf − μ0)`` (mean change over variance, element by element); as they
correlate with motor speed they are summarised by the function of speed
``w(v) = sech(β·|v|)·tanh(α·|v|)`` so that they carry over to other trajectories.

Units: speed ``v`` in rad/s (motor side); ``α``, ``β`` in s/rad; weights dimensionless.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.optimize import least_squares

#: Published fit for the default joint (docs/ALGORITHMS.md §4) [s/rad].
DEFAULT_ALPHA = 1.45e-2
DEFAULT_BETA = 4.55e-2


class WeightFitError(ValueError):
    """Labelled batches that cannot give weights (shapes, too few batches, no variance)."""


@dataclass(frozen=True)
class WeightFunction:
    """``w(v) = sech(β·|v|)·tanh(α·|v|)``: 0 at standstill, peak near ``v ≈ 1/√(αβ)``-ish, → 0 at
    high speed. Defined for negative speeds through ``|v|`` (friction is odd in ``v``, the weight of
    a sample does not depend on the direction). Dimensionless, in [0, 1)."""

    alpha: float = DEFAULT_ALPHA
    beta: float = DEFAULT_BETA

    def __post_init__(self) -> None:
        for name in ("alpha", "beta"):
            value = getattr(self, name)
            if not (np.isfinite(value) and value >= 0):
                raise ValueError(f"WeightFunction.{name}: must be finite and >= 0 [s/rad], got {value}")

    def __call__(self, speed: ArrayLike) -> NDArray[np.float64]:
        a = np.abs(np.asarray(speed, dtype=float))
        # sech(x) = 1/cosh(x); cosh overflows to inf for x > ~710, giving the correct limit 0.
        with np.errstate(over="ignore"):
            return np.tanh(self.alpha * a) / np.cosh(self.beta * a)

    def to_dict(self) -> dict[str, Any]:
        return {"alpha": float(self.alpha), "beta": float(self.beta)}

    @classmethod
    def from_dict(cls, values: dict[str, Any]) -> "WeightFunction":
        return cls(alpha=float(values.get("alpha", DEFAULT_ALPHA)), beta=float(values.get("beta", DEFAULT_BETA)))


def fit_index_weights(healthy: ArrayLike, faulty: ArrayLike) -> NDArray[np.float64]:
    """Per-index weights ``w* = (μf − μ0) / (σf² + σ0²)`` from labelled batches, scaled to max |w*| = 1.

    ``healthy`` and ``faulty`` are (n_batches, n_elements) arrays whose columns are aligned (the same
    sample of the repeated trajectory in every batch), both recorded under the disturbance spread.
    Elements with zero total variance get weight 0.
    """
    h = np.asarray(healthy, dtype=float)
    f = np.asarray(faulty, dtype=float)
    if h.ndim != 2 or f.ndim != 2 or h.shape[1] != f.shape[1]:
        raise WeightFitError(f"fit_index_weights: need two (n_batches, n_elements) arrays with the same "
                             f"n_elements, got {h.shape} and {f.shape}")
    if min(h.shape[0], f.shape[0]) < 2:
        raise WeightFitError("fit_index_weights: need >= 2 batches per class to estimate variances")
    if not (np.all(np.isfinite(h)) and np.all(np.isfinite(f))):
        raise WeightFitError("fit_index_weights: batches contain NaN/inf; drop those batches first")
    change = f.mean(axis=0) - h.mean(axis=0)
    variance = f.var(axis=0, ddof=1) + h.var(axis=0, ddof=1)
    w = np.divide(change, variance, out=np.zeros_like(change), where=variance > 0)
    peak = np.abs(w).max()
    if not peak > 0:
        raise WeightFitError("fit_index_weights: no mean change between healthy and faulty batches")
    return w / peak


def _shape(v: NDArray[np.float64], alpha: float, beta: float) -> NDArray[np.float64]:
    with np.errstate(over="ignore"):
        return np.tanh(alpha * v) / np.cosh(beta * v)


def _projected_residual(log_ab: NDArray[np.float64], v: NDArray[np.float64], w: NDArray[np.float64],
                        root_count: NDArray[np.float64] | None = None) -> NDArray[np.float64]:
    """Residual ``√n·(c(α, β)·f(v; α, β) − w)`` with the scale ``c`` eliminated by least squares
    (``n``: samples per distinct speed, ``w`` their mean weight)."""
    f = _shape(v, float(np.exp(log_ab[0])), float(np.exp(log_ab[1])))
    if root_count is not None:
        f, w = f * root_count, w * root_count
    ff = float((f * f).sum())             # elementwise, not BLAS dot (threads spin on busy hosts)
    scale = float((f * w).sum()) / ff if ff > 0 else 0.0
    return scale * f - w


def fit_weight_function(speeds: ArrayLike, index_weights: ArrayLike,
                        bounds: tuple[float, float] = (1e-4, 1.0), n_start: int = 40,
                        n_polish: int = 4) -> tuple[float, float]:
    """Fit ``(α, β)`` of ``c·sech(β|v|)·tanh(α|v|)`` to per-index weights by bounded least squares.

    The index weights are made direction independent first (multiplied by ``sign(v)``: a wear
    change of the odd friction torque is negative at negative speed) and scaled to max |w| = 1. The
    scale ``c`` is a nuisance parameter eliminated in closed form (variable projection), so only
    the shape is fitted: ``scipy.optimize.least_squares`` over ``(log α, log β)`` within ``bounds``
    [s/rad], started from the ``n_polish`` best points of an ``n_start × n_start`` log-spaced grid
    (the cost has long curved valleys with local minima; one start is not enough). Samples at
    ``v = 0`` carry no information on the shape and are ignored.
    """
    v_all = np.asarray(speeds, dtype=float).reshape(-1)
    w_all = np.asarray(index_weights, dtype=float).reshape(-1)
    if v_all.shape != w_all.shape:
        raise WeightFitError(f"fit_weight_function: {v_all.size} speeds vs {w_all.size} weights")
    keep = np.isfinite(v_all) & np.isfinite(w_all) & (v_all != 0)
    v, w = np.abs(v_all[keep]), (w_all * np.sign(v_all))[keep]
    if v.size < 3:
        raise WeightFitError("fit_weight_function: need >= 3 samples at non-zero speed")
    peak = np.abs(w).max()
    if not peak > 0:
        raise WeightFitError("fit_weight_function: all weights are zero")
    w = w / peak
    # samples at the same speed (plateaus) enter as their mean with weight √count: same minimiser
    v, inverse, counts = np.unique(v, return_inverse=True, return_counts=True)
    w = np.bincount(inverse, weights=w) / counts
    root_count = np.sqrt(counts.astype(float))
    lo, hi = np.log(bounds[0]), np.log(bounds[1])
    grid = np.linspace(lo, hi, n_start)
    costs = sorted((float(np.sum(_projected_residual(np.array([a, b]), v, w, root_count) ** 2)), a, b)
                   for a in grid for b in grid)
    best = None
    for _, a0, b0 in costs[:n_polish]:
        fit = least_squares(_projected_residual, np.array([a0, b0]), args=(v, w, root_count),
                            bounds=([lo, lo], [hi, hi]),
                            xtol=1e-15, ftol=1e-15, gtol=1e-15)
        if best is None or fit.cost < best.cost:
            best = fit
    assert best is not None    # the start grid is never empty
    return float(np.exp(best.x[0])), float(np.exp(best.x[1]))
