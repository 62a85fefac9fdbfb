"""The shift of H0 closest to an estimate in the nominal's metric (edge_monitor/stats/null_projection.py),
against scipy's bounded least squares, and what it changes for the joint vector's GLR."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.optimize import lsq_linear

from edge_monitor.stats.densities import GaussianMixture
from edge_monitor.stats.glr_batch import BatchWindowedGLR, MixtureBatch
from edge_monitor.stats.glr_gaussian import GaussianBatchGLR
from edge_monitor.stats.null_projection import BoxProjector, box_projection


def _reference(delta: np.ndarray, lower: np.ndarray, upper: np.ndarray, precision: np.ndarray) -> np.ndarray:
    """scipy: min ‖Lᵀ(Δ − x)‖² over the box, P = L·Lᵀ."""
    chol = np.linalg.cholesky(precision)
    return lsq_linear(chol.T, chol.T @ delta, bounds=(lower, upper), method="bvls", tol=1e-12).x


def _cost(delta: np.ndarray, x: np.ndarray, precision: np.ndarray) -> float:
    r = delta - x
    return float(r @ precision @ r)


def _precision(rng: np.random.Generator, d: int) -> np.ndarray:
    a = rng.normal(size=(d, d))
    cov = a @ a.T + 0.05 * np.eye(d)
    return np.linalg.inv(cov)


@settings(max_examples=200, deadline=None)
@given(seed=st.integers(0, 2**32 - 1), d=st.integers(1, 3), one_sided=st.booleans())
def test_the_projection_is_scipys_bounded_least_squares(seed, d, one_sided):
    rng = np.random.default_rng(seed)
    precision = _precision(rng, d)
    upper = rng.uniform(0.0, 1.5, d)
    lower = np.full(d, -np.inf) if one_sided else -rng.uniform(0.0, 1.5, d)
    delta = rng.normal(scale=2.0, size=(1, 6, d))
    got = box_projection(delta, lower[None], upper[None], precision[None])[0]
    for row, x in zip(delta[0], got):
        assert np.all(x >= lower - 1e-9) and np.all(x <= upper + 1e-9)
        ref = _reference(row, lower, upper, precision)
        # the optimum's cost is unique (the point is, P being definite); lsq_linear stops at tol
        assert _cost(row, x, precision) == pytest.approx(_cost(row, ref, precision), rel=1e-6, abs=1e-9)
        assert _cost(row, x, precision) <= _cost(row, np.clip(row, lower, upper), precision) + 1e-12


def test_inside_the_box_and_in_one_dimension_it_is_clip():
    rng = np.random.default_rng(1)
    delta = rng.normal(size=(4, 10, 1))
    lower, upper = np.full((4, 1), -0.5), np.full((4, 1), 0.7)
    precision = rng.uniform(0.5, 3.0, (4, 1, 1))
    assert np.array_equal(box_projection(delta, lower, upper, precision), np.clip(delta, -0.5, 0.7))
    inside = np.full((2, 3, 3), 0.1)
    projector = BoxProjector(np.full((2, 3), -np.inf), np.full((2, 3), 0.5), np.stack([np.eye(3)] * 2))
    assert np.array_equal(projector(inside), inside)


def test_a_shift_along_one_of_two_correlated_axes_is_explained_by_the_other():
    """ρ = 0.9, allowance 0.75 on both axes, the estimate (0, 1.2): clipping leaves the first axis at 0
    and weighs the excess 0.45 with 1/(1 − ρ²) ≈ 5.3; H0's nearest point moves the first axis by −ρ·0.45
    (inside its box), so that the residual (0.405, 0.45) lies along the correlation, and leaves the
    plain 0.45² of the second axis' marginal."""
    rho = 0.9
    cov = np.array([[1.0, rho], [rho, 1.0]])
    precision = np.linalg.inv(cov)
    delta = np.array([[[0.0, 1.2]]])
    upper, lower = np.full((1, 2), 0.75), np.full((1, 2), -np.inf)
    x = box_projection(delta, lower, upper, precision[None])[0, 0]
    clipped = np.clip(delta[0, 0], lower[0], upper[0])
    assert _cost(delta[0, 0], clipped, precision) == pytest.approx(0.45**2 / (1 - rho**2))
    assert _cost(delta[0, 0], x, precision) == pytest.approx(0.45**2)
    assert x[1] == pytest.approx(0.75) and x[0] == pytest.approx(-rho * 0.45)
    # a shift along the correlation (both axes up, the signature of wear) loses nothing
    both = np.array([[[1.2, 1.2]]])
    x = box_projection(both, lower, upper, precision[None])[0, 0]
    assert np.allclose(x, [0.75, 0.75])


def test_the_gaussian_fast_path_and_the_general_glr_agree_with_the_projection():
    """The calibration's closed form and the detector's general recursion give the same statistics
    (3-d, correlated, one-sided with an allowance), so the threshold is calibrated for what runs."""
    rng = np.random.default_rng(7)
    b, d = 5, 3
    covs = np.stack([np.linalg.inv(_precision(rng, d)) for _ in range(b)])
    means = rng.normal(size=(b, d))
    sd = np.sqrt(np.einsum("bii->bi", covs))
    box = (np.full((b, d), -np.inf), 0.75 * sd)
    clip = (means - 3 * sd, means + 3 * sd)
    fast = GaussianBatchGLR(means, covs, window=20, gamma0=0.6, rho=1.0, null_box=box, clip=clip)
    general = BatchWindowedGLR(MixtureBatch([GaussianMixture(np.ones(1), means[i][None], covs[i]) for i in range(b)]),
                               window=20, gamma0=0.6, rho=1.0, null_box=box, clip=clip)
    shift = np.array([0.0, 0.0, 1.5]) * sd                     # along one axis only
    for t in range(60):
        y = means + np.einsum("bij,bj->bi", np.linalg.cholesky(covs), rng.normal(size=(b, d)))
        y = y + (shift if t >= 20 else 0.0)
        assert np.allclose(fast.update(y), general.update(y), rtol=1e-9, atol=1e-9)
