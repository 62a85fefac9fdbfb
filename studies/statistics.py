"""Small statistics the studies share: the 95 % interval of a Poisson count's ratio to its expectation, and the
variance ratio that tells a slowly wandering series from an independent one."""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray
from scipy.stats import chi2


def poisson_interval(k: int, mean: float) -> tuple[float, float]:
    """95 % interval of the ratio k / mean for a Poisson count k."""
    lo = chi2.ppf(0.025, 2 * k) / 2 if k else 0.0
    return lo / mean, chi2.ppf(0.975, 2 * k + 2) / 2 / mean


def variance_ratio(z: NDArray[np.float64], k: int) -> float:
    """k·var(k-value block means)/var of a centred series ``z`` (its whole k-blocks): 1 for independent
    values, larger for a slow wander."""
    n = z.size // k
    return float(k * z[:n * k].reshape(n, k).mean(axis=1).var() / z.var())
