"""Disturbance-rejecting sample weights for the distribution-domain detector (ALGORITHMS.md §4).

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

#: Published fit for the default joint (ALGORITHMS.md §4) [s/rad].
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


def fit_weight_function(speeds: ArrayLike, index_weights: ArrayLike,
                        start: tuple[float, float] = (DEFAULT_ALPHA, DEFAULT_BETA),
                        bounds: tuple[float, float] = (1e-5, 10.0)) -> tuple[float, float]:
    """Fit ``(α, β)`` of ``c·sech(β|v|)·tanh(α|v|)`` to per-index weights by bounded least squares.

    The index weights are made direction independent first (multiplied by ``sign(v)``: a wear
    change of the odd friction torque is negative at negative speed) and scaled to max = 1; the
    scale ``c`` is a free nuisance parameter, so only the shape is fitted. ``α, β`` are bounded to
    ``bounds`` [s/rad]. Samples at |v| = 0 carry no information on the shape and are ignored.
    """
    v = np.asarray(speeds, dtype=float).reshape(-1)
    w = np.asarray(index_weights, dtype=float).reshape(-1)
    if v.shape != w.shape:
        raise WeightFitError(f"fit_weight_function: {v.size} speeds vs {w.size} weights")
    keep = np.isfinite(v) & np.isfinite(w) & (v != 0)
    v, w = np.abs(v[keep]), (w * np.sign(np.asarray(speeds, dtype=float).reshape(-1)))[keep]
    if v.size < 3:
        raise WeightFitError("fit_weight_function: need >= 3 samples at non-zero speed")
    peak = np.abs(w).max()
    if not peak > 0:
        raise WeightFitError("fit_weight_function: all weights are zero")
    w = w / peak

    def residual(theta: NDArray[np.float64]) -> NDArray[np.float64]:
        alpha, beta, scale = theta
        with np.errstate(over="ignore"):
            return scale * np.tanh(alpha * v) / np.cosh(beta * v) - w

    lo, hi = bounds
    best = None
    for a0 in (start[0], 1e-3, 1e-1):          # a few starts: the problem has flat directions
        for b0 in (start[1], 1e-3, 1e-1):
            x0 = np.clip([a0, b0, 1.0], [lo, lo, -np.inf], [hi, hi, np.inf])
            fit = least_squares(residual, x0, bounds=([lo, lo, -np.inf], [hi, hi, np.inf]))
            if best is None or fit.cost < best.cost:
                best = fit
    return float(best.x[0]), float(best.x[1])
