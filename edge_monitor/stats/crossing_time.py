"""When a degrading level first reaches a critical value: the distribution of the crossing time T
[cycles] from a trend model's state (docs/PROGNOSIS.md).

Two forms, both vectorised over horizons ``h`` [cycles from now] and both with the model's parameter
uncertainty integrated out:

* :func:`gaussian_crossing_cdf`: the level at ``h`` is Gaussian, ``N(m(h), v(h))`` (a Kalman trend's
  prediction), and ``P(T ≤ h) = max over h' ≤ h of P(level(h') ≥ L)`` — exact for a level that never
  falls (wear), a lower bound otherwise;
* :func:`wiener_crossing_cdf`: a Wiener process with drift μ and diffusion σ² per cycle from the level
  w; for known (w, μ) T is inverse Gaussian (mean (L − w)/μ, shape (L − w)²/σ²), defective for μ ≤ 0:
  ``P(T ≤ h) = Φ((μh − d)/(σ√h)) + e^{2μd/σ²}·Φ((−μh − d)/(σ√h))``, d = L − w. The uncertain (w, μ) of
  the filter are integrated by Gauss–Hermite quadrature.

:func:`quantiles` inverts a CDF given on a horizon grid (``None`` where it never reaches the level).
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import NDArray
from scipy.special import log_ndtr, ndtr

#: Gauss–Hermite nodes (probabilists') and weights of the rate and of the level.
_RATE_NODES, _RATE_WEIGHTS = np.polynomial.hermite_e.hermegauss(24)
_LEVEL_NODES, _LEVEL_WEIGHTS = np.polynomial.hermite_e.hermegauss(7)
_RATE_WEIGHTS = _RATE_WEIGHTS / _RATE_WEIGHTS.sum()
_LEVEL_WEIGHTS = _LEVEL_WEIGHTS / _LEVEL_WEIGHTS.sum()


def horizon_grid(longest: float, points: int = 160) -> NDArray[np.float64]:
    """Horizons [cycles] from 1 to ``longest``, geometrically spaced (``points`` of them, ≥ 2)."""
    return np.geomspace(1.0, max(float(longest), 2.0), max(int(points), 2))


def gaussian_crossing_cdf(mean: NDArray[np.float64], var: NDArray[np.float64], level: float,
                          now: float = 0.0) -> NDArray[np.float64]:
    """``P(T ≤ h)`` for each horizon of a grid (increasing), given the level's predictive ``mean`` and
    ``var`` there; ``now``: P(the level is already ≥ ``level``), the floor of every horizon."""
    z = (np.asarray(mean, dtype=float) - level) / np.sqrt(np.maximum(var, 1e-300))
    return np.maximum.accumulate(np.maximum(ndtr(z), now))


def wiener_crossing_cdf(h: NDArray[np.float64], level: float, w: float, var_w: float, mu: float, var_mu: float,
                        diffusion: float) -> NDArray[np.float64]:
    """``P(T ≤ h)`` of a Wiener process with drift from ``w`` to ``level`` (see the module docstring),
    with ``w ~ N(w, var_w)`` and ``μ ~ N(mu, var_mu)`` integrated out; ``diffusion`` σ² [wear²/cycle] > 0."""
    h = np.asarray(h, dtype=float)[None, None, :]
    levels = (w + math.sqrt(max(var_w, 0.0)) * _LEVEL_NODES)[:, None, None]
    rates = (mu + math.sqrt(max(var_mu, 0.0)) * _RATE_NODES)[None, :, None]
    d = np.maximum(level - levels, 0.0)
    sigma = math.sqrt(diffusion)
    root = sigma * np.sqrt(h)
    first = ndtr((rates * h - d) / root)
    with np.errstate(over="ignore"):
        second = np.exp(np.minimum(2.0 * rates * d / diffusion + log_ndtr((-rates * h - d) / root), 0.0))
    cdf = np.where(d > 0, np.clip(first + second, 0.0, 1.0), 1.0)
    weights = _LEVEL_WEIGHTS[:, None, None] * _RATE_WEIGHTS[None, :, None]
    return np.maximum.accumulate((weights * cdf).sum(axis=(0, 1)))


def quantiles(h: NDArray[np.float64], cdf: NDArray[np.float64], probabilities: tuple[float, ...]
              ) -> list[float | None]:
    """The horizons [cycles] where a non-decreasing ``cdf`` on the grid ``h`` reaches each probability
    (log-linear interpolation; the first horizon where it is reached there already); ``None`` where it
    never does within the grid."""
    out: list[float | None] = []
    for p in probabilities:
        if cdf[-1] < p:
            out.append(None)
            continue
        i = int(np.searchsorted(cdf, p, side="left"))
        if i == 0:
            out.append(float(h[0]))
            continue
        lo, hi = cdf[i - 1], cdf[i]
        frac = 0.0 if hi <= lo else (p - lo) / (hi - lo)
        out.append(float(math.exp(math.log(h[i - 1]) + frac * (math.log(h[i]) - math.log(h[i - 1])))))
    return out


def probability_within(h: NDArray[np.float64], cdf: NDArray[np.float64], horizon: float) -> float:
    """``P(T ≤ horizon)`` from the CDF on the grid (log-linear interpolation, the first value below the
    grid, the last above it: the grid is made to reach beyond every horizon asked)."""
    if horizon <= h[0]:
        return float(cdf[0])
    if horizon >= h[-1]:
        return float(cdf[-1])
    return float(np.interp(math.log(horizon), np.log(h), cdf))
