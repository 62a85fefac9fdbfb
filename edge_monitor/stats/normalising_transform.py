"""A per-axis Yeo–Johnson transform that makes a detector's nominal values closer to Gaussian
(docs/ALGORITHMS.md §6, docs/DETECTION.md "Two stages").

A Gaussian nominal density is stable to learn (its threshold hardly moves between learning windows),
but a skewed quantity then has the wrong tails: log ``kl.raw`` of a warm joint is left-skewed, so a
Gaussian fitted to it overstates its right tail and the detector alarms less often than stated. The
transform fixes the shape, the Gaussian the location and scale:

``z = YJ((y − m) / s; λ)`` per axis, with ``m``, ``s`` the mean and standard deviation of the learning
values and λ their maximum-likelihood Yeo–Johnson exponent (:func:`scipy.stats.yeojohnson_normmax`),
clipped to [``LAMBDA_MIN``, ``LAMBDA_MAX``]; axes not selected keep λ = 1, the identity on the
standardised values (a Gaussian fit does not notice the standardisation). The map is strictly
increasing, so an increase of ``y`` is an increase of ``z``.
"""

from __future__ import annotations

from typing import Any, Sequence

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy import stats

#: Bounds on the fitted exponent. Inside [0, 2] both branches are unbounded, so the map is onto the reals:
#: a fault however large moves z as far (λ < 0 would cap z from above, blinding an increase detector)
#: and the inverse is defined everywhere. The KL distances of warm joints fit λ̂ = 0.7 … 1.3 (on 240
#: Gaussian values λ̂ has standard deviation 0.08 around 1).
LAMBDA_MIN, LAMBDA_MAX = 0.0, 2.0

TRANSFORMS: tuple[str, ...] = ("none", "yeo-johnson")


class TransformError(ValueError):
    """Values unusable for fitting the transform (too few, non-finite, constant) or a damaged state."""


def yeo_johnson(u: ArrayLike, lam: ArrayLike) -> NDArray[np.float64]:
    """Yeo–Johnson of ``u`` with exponent ``lam``, both broadcast (one λ, or one per row of a fleet)."""
    u, lam = np.broadcast_arrays(np.asarray(u, dtype=float), np.asarray(lam, dtype=float))
    log_up = np.log1p(np.abs(u))                 # log(1 + u) for u ≥ 0, log(1 − u) below
    zero, two = np.abs(lam) < 1e-12, np.abs(lam - 2) < 1e-12
    with np.errstate(over="ignore", invalid="ignore"):   # (1 + u)^λ beyond ≈ 1e308: inf, which the detector skips
        up = np.where(zero, log_up, np.expm1(lam * log_up) / np.where(zero, 1.0, lam))
        down = np.where(two, -log_up, -np.expm1((2 - lam) * log_up) / np.where(two, 1.0, 2 - lam))
    return np.where(u >= 0, up, down)


def _yj_inverse(z: NDArray[np.float64], lam: float) -> NDArray[np.float64]:
    """Inverse of :func:`yeo_johnson` (z ≥ 0 ↔ u ≥ 0). Values beyond the image of the reals (only for λ < 0 or
    λ > 2, outside the fitted range) map to ±inf."""
    out = np.empty_like(z)
    pos = z >= 0
    zp, zn = z[pos], z[~pos]
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        out[pos] = np.expm1(zp) if abs(lam) < 1e-12 else np.expm1(np.log1p(lam * zp) / lam)
        out[~pos] = (-np.expm1(-zn) if abs(lam - 2) < 1e-12
                     else -np.expm1(np.log1p(-(2 - lam) * zn) / (2 - lam)))
    return np.where(np.isnan(out), np.where(pos, np.inf, -np.inf), out)


class YeoJohnson:
    """Per-axis ``z = YJ((y − m)/s; λ)`` (see the module docstring). ``center``, ``scale`` in the units
    of ``y``; ``lambdas`` dimensionless; all (d,)."""

    def __init__(self, center: ArrayLike, scale: ArrayLike, lambdas: ArrayLike) -> None:
        self.center = np.asarray(center, dtype=float).ravel()
        self.scale = np.asarray(scale, dtype=float).ravel()
        self.lambdas = np.asarray(lambdas, dtype=float).ravel()
        ok = (self.center.size == self.scale.size == self.lambdas.size >= 1
              and np.all(np.isfinite(self.center)) and np.all(np.isfinite(self.scale))
              and np.all(self.scale > 1e-12 * np.maximum(1.0, np.abs(self.center)))
              and np.all((self.lambdas >= LAMBDA_MIN) & (self.lambdas <= LAMBDA_MAX)))
        if not ok:
            raise TransformError(f"Yeo-Johnson parameters invalid: center {self.center.tolist()}, "
                                 f"scale {self.scale.tolist()}, lambdas {self.lambdas.tolist()}")

    @classmethod
    def fit(cls, values: ArrayLike, axes: Sequence[bool] = ()) -> "YeoJohnson":
        """Fit to learning values (n, d) (or (n,)): mean, sd (ddof = 1) and the ML exponent of each axis
        selected by ``axes`` (d booleans; empty: all), λ = 1 for the others."""
        arr = np.asarray(values, dtype=float)
        arr = arr[:, None] if arr.ndim == 1 else arr
        if arr.ndim != 2 or len(arr) < 3 or not np.all(np.isfinite(arr)):
            raise TransformError(f"Yeo-Johnson: need at least 3 rows of finite values, got shape {arr.shape}")
        center, scale = arr.mean(axis=0), arr.std(axis=0, ddof=1)
        if not np.all(scale > 0):
            raise TransformError("Yeo-Johnson: constant learning values")
        u = (arr - center) / scale
        selected = list(axes) or [True] * arr.shape[1]
        if len(selected) != arr.shape[1]:
            raise TransformError(f"Yeo-Johnson: {len(selected)} axis flags for {arr.shape[1]} columns")
        lambdas = [float(np.clip(stats.yeojohnson_normmax(col), LAMBDA_MIN, LAMBDA_MAX)) if on else 1.0
                   for col, on in zip(u.T, selected)]
        return cls(center, scale, lambdas)

    @property
    def dim(self) -> int:
        return int(self.center.size)

    def apply(self, y: ArrayLike) -> NDArray[np.float64]:
        """z for ``y`` of shape (d,) or (n, d); same shape back."""
        arr = np.asarray(y, dtype=float)
        u = (arr.reshape(-1, self.dim) - self.center) / self.scale
        z = yeo_johnson(u, self.lambdas)
        return z.reshape(arr.shape)

    def invert(self, z: ArrayLike) -> NDArray[np.float64]:
        """y for ``z`` of shape (d,) or (n, d)."""
        arr = np.asarray(z, dtype=float)
        z2 = arr.reshape(-1, self.dim)
        u = np.column_stack([_yj_inverse(z2[:, k], float(lam)) for k, lam in enumerate(self.lambdas)])
        return (self.center + self.scale * u).reshape(arr.shape)

    def shift_in_units(self, z_mean: ArrayLike, delta_z: ArrayLike) -> tuple[float, ...]:
        """A shift ``delta_z`` of the transformed nominal mean ``z_mean``, in the units of ``y``:
        ``T⁻¹(z̄ + Δz) − T⁻¹(z̄)`` per axis."""
        base = np.asarray(z_mean, dtype=float).ravel()
        moved = self.invert(base + np.asarray(delta_z, dtype=float).ravel())
        return tuple(float(v) for v in moved - self.invert(base))

    def state_dict(self) -> dict[str, Any]:
        return {"kind": "yeo-johnson", "center": self.center.tolist(), "scale": self.scale.tolist(),
                "lambdas": self.lambdas.tolist()}

    @classmethod
    def from_state(cls, state: dict[str, Any]) -> "YeoJohnson":
        try:
            return cls(state["center"], state["scale"], state["lambdas"])
        except (KeyError, TypeError, ValueError) as exc:
            raise TransformError(f"saved Yeo-Johnson transform unusable: {exc}") from None

