"""The closed-form Gaussian GLR gives the general mixture code's statistics (edge_monitor/stats/glr_gaussian.py)."""

from __future__ import annotations

import numpy as np
import pytest

from edge_monitor.stats.densities import fit_density
from edge_monitor.stats.glr_batch import BatchWindowedGLR, MixtureBatch, clip_range, null_box, stack_bounds
from edge_monitor.stats.glr_gaussian import GaussianBatchGLR


@pytest.mark.parametrize("dim,direction,allowance,clip", [(1, "increase", 0.75, 3.0), (1, "both", 0.0, 0.0),
                                                          (3, "increase", 0.75, 3.0), (2, "both", 0.5, 2.0)])
def test_same_statistics_as_the_general_code(dim: int, direction: str, allowance: float, clip: float) -> None:
    rng = np.random.default_rng(dim + int(10 * allowance))
    cov = np.eye(dim) + 0.6 * (np.ones((dim, dim)) - np.eye(dim))
    nominals = [rng.multivariate_normal(np.arange(dim), cov, size=60) for _ in range(5)]
    mixtures = [fit_density(n, "gauss") for n in nominals]
    boxes = stack_bounds([null_box(n, direction, allowance) for n in nominals])
    clips = stack_bounds([clip_range(n, clip) for n in nominals])
    general = BatchWindowedGLR(MixtureBatch(mixtures), 20, 0.6, 1.0, "recursive", null_box=boxes, clip=clips)
    fast = GaussianBatchGLR(np.array([m.means[0] for m in mixtures]), np.array([m.cov for m in mixtures]),
                            20, 0.6, 1.0, boxes, clips)
    stream = rng.multivariate_normal(np.arange(dim) + 0.3, cov, size=(90, 5))
    for t in range(stream.shape[0]):
        np.testing.assert_allclose(fast.update(stream[t]), general.update(stream[t]), rtol=1e-9, atol=1e-11)
