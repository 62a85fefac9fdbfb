"""What a threshold calibration draws its simulated data from (:mod:`edge_monitor.stats.calibration`):
a fitted density, or the learned values themselves through a smoothed bootstrap (docs/ALGORITHMS.md §6,
"the steady threshold simulated from the values")."""

from __future__ import annotations

import math
from typing import Protocol

import numpy as np
from numpy.typing import NDArray

from edge_monitor.stats.densities import DensityError


class Sampler(Protocol):
    """What the calibration draws nominal sets and streams from."""

    @property
    def dim(self) -> int: ...

    def sample(self, n: int, rng: np.random.Generator) -> NDArray[np.float64]: ...


class SmoothedBootstrap:
    """Draws shaped as the nominal values (N0 × d) themselves: a value picked at random plus Gaussian
    noise of covariance h²·Ŝ (Ŝ: the values' covariance, h: Silverman's factor
    (4/(d+2))^(1/(d+4))·N0^(−1/(d+4))), shrunk towards the mean by 1/√(1 + h²) — the smoothed
    bootstrap that keeps the values' mean and covariance (Silverman 1986, §6.4.1) and their shape
    (skew, tails, dependence between axes) up to the smoothing."""

    def __init__(self, values: NDArray[np.float64]) -> None:
        n, self.dim = values.shape
        self.values, self.mean = values, values.mean(axis=0)
        self.h = (4.0 / (self.dim + 2)) ** (1.0 / (self.dim + 4)) * n ** (-1.0 / (self.dim + 4))
        try:
            self._chol = np.linalg.cholesky(np.atleast_2d(np.cov(values, rowvar=False, ddof=1)))
        except np.linalg.LinAlgError as exc:
            raise DensityError("the nominal values are degenerate (singular covariance)") from exc

    def sample(self, n: int, rng: np.random.Generator) -> NDArray[np.float64]:
        """n draws, (n, d)."""
        picked = self.values[rng.integers(0, len(self.values), n)]
        noise = self.h * rng.standard_normal((n, self.dim)) @ self._chol.T
        return self.mean + (picked - self.mean + noise) / math.sqrt(1.0 + self.h ** 2)
