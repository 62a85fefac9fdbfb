"""Batch EM and SA-EM estimates of a bias change Δ (docs/ALGORITHMS.md §6)."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from edge_monitor.stats.bias_em import BiasEMError, SAEMBias, em_bias
from edge_monitor.stats.densities import GaussianMixture, fit_gaussian, fit_gce, fit_kde


def skewed_mixture() -> GaussianMixture:
    return fit_gce(np.random.default_rng(10).gamma(2.0, size=(200, 1)))


def test_em_for_one_gaussian_is_the_mean_difference() -> None:
    rng = np.random.default_rng(0)
    density = fit_gaussian(rng.normal(size=(100, 2)))
    y = rng.normal(size=(30, 2)) + [0.5, -1.0]
    np.testing.assert_allclose(em_bias(y, density), y.mean(axis=0) - density.means[0])


@pytest.mark.parametrize("accelerate", [True, False])
def test_em_reaches_a_maximum_of_the_shifted_likelihood(accelerate: bool) -> None:
    density = skewed_mixture()
    y = np.random.default_rng(1).gamma(2.0, size=(80, 1)) + 0.7
    delta = em_bias(y, density, accelerate=accelerate)

    def loglik(d: float) -> float:
        return float(density.logpdf(y - d).sum())
    eps = 1e-4
    gradient = (loglik(delta[0] + eps) - loglik(delta[0] - eps)) / (2 * eps)
    # at the stopping rule ‖step‖² ≤ 1e-10 the gradient is ≤ n·F·1e-5·(1/(1−rate)) ≈ 1e-2
    assert abs(gradient) < 2e-2
    assert loglik(delta[0]) >= max(loglik(delta[0] + 0.01), loglik(delta[0] - 0.01))


def test_em_recovers_a_known_shift_within_its_cramer_rao_bound() -> None:
    density = skewed_mixture()
    rng = np.random.default_rng(2)
    n, true_shift = 5000, 0.8
    y = density.sample(n, rng) + true_shift
    delta = em_bias(y, density)[0]
    crlb_sd = 1.0 / math.sqrt(n * density.fisher_location()[0, 0])
    assert abs(delta - true_shift) <= 4 * crlb_sd        # 4 standard deviations of an efficient estimate


def test_literal_sa_em_step_is_the_algorithms_formula() -> None:
    density = skewed_mixture()
    sa = SAEMBias(density, gamma0=0.6, rho=1.0, step="em")
    ys = [3.0, 2.5, 4.0]
    delta = 0.0
    for n, y in enumerate(ys, start=1):
        gain = 0.6 * n ** -1.0
        zeta = density.responsibilities(np.array([[y - delta]]))[0]
        delta = gain * float(np.sum(zeta * (y - density.means[:, 0]))) + (1 - gain) * delta
        assert sa.update(y)[0] == pytest.approx(delta, rel=1e-12)


def test_sa_em_converges_to_batch_em_on_a_long_stationary_segment() -> None:
    density = skewed_mixture()
    rng = np.random.default_rng(3)
    n, true_shift = 20_000, 1.0
    y = density.sample(n, rng) + true_shift
    sa = SAEMBias(density)
    for value in y:
        estimate = sa.update(value)
    batch = em_bias(y, density)
    # Linearised, Δ̂_SA − Δ* = Σ wj ψj + Π(1 − γi)·(0 − Δ*) with wj = γj Π_{i>j}(1 − γi) and
    # ψ = F⁻¹·score (sd F^(−1/2), model well specified), while the MLE is (1/n)Σ ψj. So the difference
    # has sd F^(−1/2)·‖w − 1/n‖ plus the deterministic remainder of the start value.
    gains = 0.6 / np.arange(1, n + 1)
    survive = np.concatenate([np.cumprod((1 - gains)[::-1])[::-1][1:], [1.0]])
    weights = gains * survive
    sd = math.sqrt(np.sum((weights - 1 / n) ** 2) / density.fisher_location()[0, 0])
    remainder = float(np.prod(1 - gains)) * true_shift
    assert abs(estimate[0] - batch[0]) <= 4 * sd + remainder
    assert sd < 0.01                                       # the bound itself is tight at this length


def test_sa_em_state_round_trip_continues_identically() -> None:
    density = fit_kde(np.random.default_rng(4).normal(size=(50, 2)))
    rng = np.random.default_rng(5)
    sa = SAEMBias(density, gamma0=0.5, rho=0.8)
    for y in rng.normal(size=(20, 2)):
        sa.update(y)
    back = SAEMBias.from_state(json.loads(json.dumps(sa.state_dict())))
    for y in rng.normal(size=(10, 2)):
        np.testing.assert_array_equal(sa.update(y), back.update(y))


@pytest.mark.parametrize("gamma0, rho", [(0.0, 1.0), (1.0, 1.0), (0.6, 0.5), (0.6, 1.2)])
def test_invalid_gain_is_refused_with_the_valid_range(gamma0: float, rho: float) -> None:
    with pytest.raises(BiasEMError, match="must lie in"):
        SAEMBias(skewed_mixture(), gamma0=gamma0, rho=rho)
