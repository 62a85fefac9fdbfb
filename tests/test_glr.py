"""GLR tests for a bias change (docs/ALGORITHMS.md §6): thresholds, miss probability, batch and windowed."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy import stats

from edge_monitor.stats.bias_em import SAEMBias
from edge_monitor.stats.densities import fit_gaussian, fit_gce, fit_kde
from edge_monitor.stats.glr import (
    GLRError,
    WindowedGLR,
    bootstrap_threshold,
    glr_known_change,
    glr_unknown_change,
    miss_probability,
    threshold_from_pf,
)


def test_thresholds_from_pf_match_the_spec_values() -> None:
    assert threshold_from_pf(0.01, 1) == pytest.approx(3.317, abs=5e-4)
    assert threshold_from_pf(0.01, 2) == pytest.approx(4.605, abs=5e-4)
    for bad in (0.0, 1.0, -0.1, 1.5, float("nan")):
        with pytest.raises(GLRError, match="between 0 and 1"):
            threshold_from_pf(bad, 1)


def test_miss_probability_limits_and_monotonicity() -> None:
    h = threshold_from_pf(0.01, 2)
    fisher = np.diag([2.0, 0.5])
    assert miss_probability([0.0, 0.0], fisher, h) == pytest.approx(0.99)
    values = [miss_probability([k, 0.5 * k], fisher, h, n=20) for k in (0.1, 0.3, 0.6, 1.0)]
    assert all(a > b for a, b in zip(values, values[1:]))
    # λ = 20·(2·1² + 0.5·0.5²) = 42.5: P(χ'²₂(42.5) ≤ 9.21) = 1.6e-4
    assert values[-1] == pytest.approx(float(stats.ncx2.cdf(2 * h, 2, 42.5)), rel=1e-9)
    assert values[-1] < 1e-3


def test_known_change_statistic_for_one_gaussian_is_closed_form() -> None:
    rng = np.random.default_rng(0)
    density = fit_gaussian(rng.normal(size=(200, 1)))
    y = rng.normal(size=(40, 1)) + 0.3
    result = glr_known_change(y, density, pf=0.01)
    z = (y.mean() - density.means[0, 0]) ** 2 / density.cov[0, 0]
    assert result.statistic == pytest.approx(0.5 * len(y) * z, rel=1e-10)
    assert result.threshold == pytest.approx(threshold_from_pf(0.01, 1))


def test_miss_probability_predicts_the_measured_miss_rate() -> None:
    # Nominal model from 20 000 points (location/scale errors < 1 %), N = 50, Δ = 0.4 σ:
    # 2s ~ χ'²₁(λ = 50·0.16) exactly for a Gaussian with known variance.
    rng = np.random.default_rng(1)
    density = fit_gaussian(rng.normal(size=(20_000, 1)))
    runs, shift = 2000, 0.4
    misses = [not glr_known_change(rng.normal(size=(50, 1)) + shift, density, 0.01).alarm for _ in range(runs)]
    predicted = miss_probability([shift], density.fisher_location(), threshold_from_pf(0.01, 1), n=50)
    # 4 binomial standard errors plus 0.02 for the residual model error (±1 % in σ̂ moves Pm by < 0.01)
    tolerance = 4 * math.sqrt(predicted * (1 - predicted) / runs) + 0.02
    assert abs(np.mean(misses) - predicted) <= tolerance


@pytest.mark.slow
@pytest.mark.parametrize("pf", [0.05, 0.01])
def test_bootstrap_threshold_calibrates_the_batch_test_with_200_nominal_points(pf: float) -> None:
    # N0 = 200, N = 50, 40 nominal sets × 100 tests. The asymptotic test is liberal here (its
    # statistic is inflated by about 1 + N/N0 = 1.25 through the nominal mean's error: ≈ 0.08 at
    # Pf = 0.05, see docs/DETECTION.md); the bootstrap threshold must be within a factor 2 of Pf.
    # With 4000 runs the binomial standard error is ≤ 0.0035 at Pf = 0.05 and ≤ 0.0016 at Pf = 0.01, so the factor-2
    # band (half-width Pf/2 on the low side) is about 3 standard errors wide or more.
    rng = np.random.default_rng(2)
    rates = []
    for s in range(40):
        nominal = rng.normal(size=(200, 1))
        density = fit_gaussian(nominal)
        h = bootstrap_threshold(nominal, density, 50, pf, n_boot=2000, seed=s)
        rates.append(np.mean([glr_known_change(rng.normal(size=(50, 1)), density, threshold=h).alarm
                              for _ in range(100)]))
    assert pf / 2 <= np.mean(rates) <= 2 * pf


def test_batch_test_detects_a_shift_and_stays_quiet_without_one() -> None:
    # skewed nominal data, GCE density, N = 50: the test must alarm at a 1σ shift in ≥ 95 % of 100 runs
    # (its predicted miss probability there is < 1e-3) and at most 2·Pf + 4 SE of the runs without one.
    rng = np.random.default_rng(3)
    density = fit_gce(rng.gamma(2.0, size=(400, 1)))
    sd = math.sqrt(2.0)
    runs = 200
    quiet = [glr_known_change(rng.gamma(2.0, size=(50, 1)), density, 0.05).alarm for _ in range(runs)]
    loud = [glr_known_change(rng.gamma(2.0, size=(50, 1)) + sd, density, 0.05).alarm for _ in range(runs)]
    assert np.mean(loud) >= 0.95
    assert np.mean(quiet) <= 2 * 0.05 + 4 * math.sqrt(0.1 * 0.9 / runs)


def test_unknown_change_time_is_located() -> None:
    rng = np.random.default_rng(4)
    density = fit_kde(rng.normal(size=(200, 1)))
    y = rng.normal(size=(80, 1))
    y[30:] += 2.0
    result = glr_unknown_change(y, density, 0.01)
    assert result.alarm
    assert abs(result.change_index - 30) <= 5          # MLE of a 2σ change point: error of a few samples
    assert result.delta[0] == pytest.approx(2.0, abs=4 / math.sqrt(50))
    windowed = glr_unknown_change(y, density, 0.01, window=20)
    assert windowed.change_index >= 60


def _brute_force(y: np.ndarray, density, window: int, mode: str) -> list[float]:
    """Independent re-implementation: one SAEMBias per candidate start, sums recomputed from scratch."""
    out = []
    base = density.logpdf(y)
    estimators: dict[int, SAEMBias] = {}
    recursive: dict[int, float] = {}
    for n in range(len(y)):
        estimators[n] = SAEMBias(density)
        recursive[n] = 0.0
        for t in [t for t in estimators if t <= n - window]:
            del estimators[t], recursive[t]
        best = -math.inf
        for t, est in estimators.items():
            delta = est.update(y[n])
            recursive[t] += float(density.logpdf(y[n] - delta)[0] - base[n])
            exact = float(np.sum(density.logpdf(y[t:n + 1] - delta) - base[t:n + 1]))
            best = max(best, exact if mode == "exact" else recursive[t])
        out.append(max(best, 0.0))
    return out


@pytest.mark.parametrize("mode", ["exact", "recursive"])
def test_windowed_glr_matches_an_independent_implementation(mode: str) -> None:
    rng = np.random.default_rng(5)
    density = fit_gce(rng.normal(size=(100, 2)))
    y = rng.normal(size=(40, 2))
    y[25:] += [1.0, -0.5]
    glr = WindowedGLR(density, window=8, pf=0.01, mode=mode)
    got = [glr.update(v).statistic for v in y]
    np.testing.assert_allclose(got, _brute_force(y, density, 8, mode), rtol=1e-9, atol=1e-9)


def test_windowed_glr_alarms_after_a_change_and_reports_it() -> None:
    rng = np.random.default_rng(6)
    density = fit_gce(rng.normal(size=(300, 1)))
    glr = WindowedGLR(density, window=50, pf=1e-4)
    decisions = [glr.update(v) for v in np.r_[rng.normal(size=100), rng.normal(size=60) + 2.0]]
    assert not any(d.alarm for d in decisions[:100])
    first = next(d for d in decisions if d.alarm)
    assert 100 <= first.index <= 115
    assert abs(first.change_index - 100) <= 5
    assert first.delta[0] > 1.0
    # at the alarm the segment is short (Pm of a short segment can be large); 30 cycles later the
    # estimated miss probability of the 2σ change is negligible: λ ≈ 30·F·Δ̂² ≫ 2h
    assert abs(decisions[130].change_index - 100) <= 5
    assert decisions[130].miss_probability < 1e-3


def test_windowed_glr_state_round_trip_continues_identically_and_is_bounded() -> None:
    rng = np.random.default_rng(7)
    density = fit_kde(rng.normal(size=(60, 1)))
    glr = WindowedGLR(density, window=30, mode="recursive")
    for v in rng.normal(size=1000):
        glr.update(v)
    size_1000 = len(json.dumps(glr.state_dict()))
    for v in rng.normal(size=1000):
        glr.update(v)
    state = json.loads(json.dumps(glr.state_dict()))
    assert abs(len(json.dumps(state)) - size_1000) < 0.02 * size_1000   # same arrays, only digits differ
    back = WindowedGLR.from_state(state)
    for v in rng.normal(size=50) + 1.0:
        assert back.update(v) == glr.update(v)


@settings(max_examples=25, deadline=None)
@given(st.lists(st.floats(-1e3, 1e3), min_size=1, max_size=40), st.sampled_from(["exact", "recursive"]))
def test_windowed_glr_statistic_is_finite_and_non_negative(values: list[float], mode: str) -> None:
    density = fit_gaussian(np.random.default_rng(8).normal(size=(30, 1)))
    glr = WindowedGLR(density, window=10, mode=mode)
    for v in values:
        d = glr.update(v)
        assert math.isfinite(d.statistic) and d.statistic >= 0.0
        assert 0.0 <= d.miss_probability <= 1.0
        assert d.index - d.change_index < 10


def test_windowed_glr_refuses_bad_settings_and_non_finite_input() -> None:
    density = fit_gaussian(np.random.default_rng(9).normal(size=(30, 1)))
    with pytest.raises(GLRError, match="window"):
        WindowedGLR(density, window=0)
    with pytest.raises(GLRError, match="mode"):
        WindowedGLR(density, mode="fast")  # type: ignore[arg-type]
    with pytest.raises(GLRError, match="finite"):
        WindowedGLR(density).update(float("nan"))


def test_chi_square_threshold_is_calibrated_when_the_nominal_model_is_accurate() -> None:
    # N0 = 20 000 (nominal errors negligible), N = 50, Pf = 0.05, Gaussian data and density: the
    # asymptotic law is exact, so the rate must be within 4 binomial SE of Pf over 3000 runs.
    rng = np.random.default_rng(10)
    density = fit_gaussian(rng.normal(size=(20_000, 1)))
    runs = 3000
    rate = np.mean([glr_known_change(rng.normal(size=(50, 1)), density, 0.05).alarm for _ in range(runs)])
    assert abs(rate - 0.05) <= 4 * math.sqrt(0.05 * 0.95 / runs)
    assert stats.chi2.isf(0.05, 1) / 2 == pytest.approx(threshold_from_pf(0.05, 1))
