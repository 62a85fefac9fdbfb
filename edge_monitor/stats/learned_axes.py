"""A vector detector's calibration with some axes in learned units (:attr:`GaussianSettings.learned_axes
<edge_monitor.stats.gaussian_calibration.GaussianSettings.learned_axes>`): those axes drawn from their measured law
as a scalar warm-up detector's are, the others keeping their learning error (docs/ALGORITHMS.md, "the warm-up's
scalar detectors calibrated for their law in learned units")."""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import NDArray

from edge_monitor.stats.gaussian_fleet import pairing, spread_draws
from edge_monitor.stats.learning_error import TILTS as FIT_TILTS
from edge_monitor.stats.learning_error import vector_fits

if TYPE_CHECKING:
    from edge_monitor.stats.gaussian_calibration import GaussianSettings


def proposal_sets(settings: GaussianSettings, tilts: tuple[float, ...]) -> int:
    """The nominals over which every combination of the importance-sampling proposals is drawn once: the learning
    error's and the drift's (:func:`pairing`, 4 with plain drift draws) and each learned axis's spread's."""
    return pairing(tilts) * len(FIT_TILTS) ** len(settings.learned_axes)


def independent_learned_axes(r: NDArray[np.float64], axes: tuple[int, ...]) -> NDArray[np.float64]:
    """R with the learned axes uncorrelated with every other: their law is measured per axis, and their fit in
    learned units holds no correlation (the table's R has none on the wear axis either)."""
    out = r.copy()
    for axis in axes:
        out[axis, :] = out[:, axis] = 0.0
        out[axis, axis] = 1.0
    return out


def partly_learned_fits(settings: GaussianSettings, index: NDArray[np.int64], r: NDArray[np.float64],
                        rng: np.random.Generator, drift_tilts: tuple[float, ...]
                        ) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]:
    """A vector's nominals whose :attr:`GaussianSettings.learned_axes` are in learned units: those axes fitted
    exactly (mean 0, sd 1, uncorrelated: :func:`independent_learned_axes`), the others' fit drawn from its exact
    law (:func:`vector_fits` on their block of R); each nominal's stream spread per axis (G, d) (1 on the other
    axes, the spread law's draw on the learned ones, from a proposal slot the learning error's and the drift's
    leave free: the k-th learned axis of nominal g takes ⌊g / (pairing·4ᵏ)⌋ mod 4) and the product of the
    importance weights."""
    d = r.shape[0]
    if len(settings.spread_mean) != d:
        raise ValueError(f"a vector's spread law needs one spread per axis ({d}), got {settings.spread_mean!r}")
    r = independent_learned_axes(r, settings.learned_axes)
    free = np.array([i for i in range(d) if i not in settings.learned_axes])
    means, covs, spread = np.zeros((index.size, d)), np.zeros((index.size, d, d)), np.ones((index.size, d))
    weight = np.ones(index.size)
    if free.size:
        sub = np.linalg.cholesky(r[np.ix_(free, free)])
        means[:, free], block, weight = vector_fits(settings.n0, index, sub, rng)
        covs[:, free[:, None], free[None, :]] = block
    for k, axis in enumerate(settings.learned_axes):     # each axis its own slot: every pair drawn equally often
        covs[:, axis, axis] = 1.0
        slot = index // (pairing(drift_tilts) * len(FIT_TILTS) ** k)
        key = (k, int(index[0])) if k else ()          # the first axis: the seed the shipped table was computed with
        spread[:, axis], w = spread_draws(settings.spread_mean[axis], settings.spread_sd[axis], slot, key)
        weight = weight * w
    return means, covs, weight, spread
