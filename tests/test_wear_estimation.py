"""Wear estimation (docs/ALGORITHMS.md §3): CRLB, the likelihood grid, bad data, Monte Carlo quality.

Monte Carlo data are made as sim_controller makes them (docs/WEAR_ESTIMATION.md §4): |τl| ~ U(0.3, 0.7),
the controller's estimate μl = τl + N(0, 0.1²), a per-cycle, per-level model error N(0, σ²) with
σ = 5.7e-3, and the extraction error N(0, 7e-5²) (passed as stderr); the lubricant temperature is
fixed per test. The full study is tools/studies/mc_wear_study.py; here fewer cycles, with tolerances derived
from the Monte Carlo standard errors of that count (0.1 % two-sided unless stated).
"""

from __future__ import annotations

import json
import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy import stats

from edge_monitor.features.wear_estimation import WearEstimate, WearEstimator
from edge_monitor.features.wear_information import crlb_wear, data_covariance
from edge_monitor.offline.experiment_design import design_speeds
from joint_model.friction import friction_magnitude

SIGMA = 5.7e-3
EXTRACTION_STDERR = 7e-5
LOAD_MEAN, LOAD_STD = 0.5, 0.1
DEFAULT_SPEEDS = [2.1, 8.7, 15.3, 21.9, 28.5, 35.1, 41.7, 82.2, 133.5, 184.7, 236.2, 287.1]
BAD_SPEEDS = [82.0, 133.0]
Z_999 = 3.29  # two-sided 0.1 % normal quantile
RECORD_KEYS = {"estimate", "std", "temperature", "upper_95", "identifiable", "posterior_mean", "evidence", "score"}


@pytest.fixture(scope="module")
def estimator() -> WearEstimator:
    return WearEstimator()


@pytest.fixture(scope="module")
def marginal_estimator() -> WearEstimator:
    return WearEstimator(method="marginal")


@pytest.fixture(scope="module")
def designs() -> dict[int, list[float]]:
    return {n: design_speeds(n).speeds for n in (1, 2, 3, 4)}


def simulate_cycles(speeds, temperature: float, wear: float, runs: int, seed: int):
    """Friction data (runs × N) and load estimates of ``runs`` cycles, as sim_controller makes them."""
    rng = np.random.default_rng(seed)
    v = np.asarray(speeds, dtype=float)
    load = rng.uniform(0.3, 0.7, runs)
    load_estimate = load + rng.normal(0.0, LOAD_STD, runs)
    tau = (friction_magnitude(v[None, :], load[:, None], temperature, wear)
           + rng.normal(0.0, SIGMA, (runs, v.size)) + rng.normal(0.0, EXTRACTION_STDERR, (runs, v.size)))
    return tau, load_estimate


def run_estimates(estimator, speeds, tau, load_estimate) -> list[WearEstimate]:
    stderr = [EXTRACTION_STDERR] * len(speeds)
    return [estimator.estimate(speeds, row, mu, LOAD_STD, friction_stderr=stderr)
            for row, mu in zip(tau, load_estimate)]


def field(results: list[WearEstimate], name: str) -> np.ndarray:
    return np.array([getattr(r, name) for r in results], dtype=float)


def chi2_band(runs: int) -> tuple[float, float]:
    """0.05 % and 99.95 % quantiles of s²/σ² for ``runs`` normal samples."""
    q_low, q_high = stats.chi2.ppf([0.0005, 0.9995], runs - 1) / (runs - 1)
    return float(q_low), float(q_high)


def coverage_floor(level: float, runs: int) -> float:
    """Smallest observed coverage consistent with a true coverage ≥ ``level`` (one-sided 0.1 %)."""
    return level - 3.09 * math.sqrt(level * (1 - level) / runs)


# ----------------------------------------------------------------------------- Cramér–Rao bound
def test_crlb_equals_brute_force_fisher_information():
    """F = JᵀΣ⁻¹J with J and s by finite differences of the model and an explicit Σ⁻¹."""
    v = np.array([5.0, 30.0, 60.0, 150.0])
    xi, wear, h = 41.0, 27.0, 1e-5
    f = lambda x, w, load=LOAD_MEAN: friction_magnitude(v, load, x, w)  # noqa: E731
    jac = np.column_stack([(f(xi + h, wear) - f(xi - h, wear)) / (2 * h),
                           (f(xi, wear + h) - f(xi, wear - h)) / (2 * h)])
    s = (f(xi, wear, LOAD_MEAN + h) - f(xi, wear, LOAD_MEAN - h)) / (2 * h)
    cov = SIGMA ** 2 * np.eye(v.size) + LOAD_STD ** 2 * np.outer(s, s)
    brute = np.linalg.inv(jac.T @ np.linalg.inv(cov) @ jac)[1, 1]
    assert crlb_wear(v, xi, wear, LOAD_MEAN, LOAD_STD) == pytest.approx(brute, rel=1e-5)


def test_crlb_is_infinite_for_one_speed_and_grows_with_extra_noise():
    assert math.isinf(crlb_wear([40.0], 40.0, 35.0, LOAD_MEAN, LOAD_STD))
    assert math.isinf(crlb_wear([40.0, 40.0], 40.0, 35.0, LOAD_MEAN, LOAD_STD))
    v = [20.0, 45.0, 90.0]
    plain = crlb_wear(v, 40.0, 35.0, LOAD_MEAN, LOAD_STD)
    noisier = crlb_wear(v, 40.0, 35.0, LOAD_MEAN, LOAD_STD, friction_stderr=[3e-3, 3e-3, 3e-3])
    assert noisier > plain


# ------------------------------------------------------------------------ the likelihood grid
def brute_force_posterior(speeds, tau, mu, sigma_l, temperature_range, wear_max=100.0):
    """Independent reference: the (ξ, ϖ) likelihood evaluated point by point with an explicit Σ⁻¹
    on a 4× finer grid; returns (marginal ML, posterior std, profile-likelihood upper bound at 1.96²,
    whether ϖ = 0 is outside that interval)."""
    v = np.asarray(speeds, dtype=float)
    cov_inv = np.linalg.inv(data_covariance(v, sigma_l, SIGMA))
    n_xi = 4 * max(100, math.ceil((temperature_range[1] - temperature_range[0]) / 0.25))
    xi = temperature_range[0] + (np.arange(n_xi) + 0.5) / n_xi * (temperature_range[1] - temperature_range[0])
    wear = np.linspace(0.0, wear_max, 801)
    resid = tau[None, None, :] - friction_magnitude(v[None, None, :], mu, xi[:, None, None], wear[None, :, None])
    cost = np.einsum("ijk,kl,ijl->ij", resid, cov_inv, resid)
    lik = np.exp(-0.5 * (cost - cost.min()))
    marginal = lik.sum(axis=0) * np.r_[0.5, np.ones(wear.size - 2), 0.5]
    post = marginal / marginal.sum()
    mean = post @ wear
    profile = cost.min(axis=0) - cost.min()
    start = int(np.argmin(profile))
    above = np.flatnonzero(profile[start:] > 1.96 ** 2)
    upper = wear[-1] if above.size == 0 else wear[start + above[0]]
    return wear[np.argmax(marginal)], math.sqrt(post @ (wear - mean) ** 2), upper, profile[0] > 1.96 ** 2


@pytest.mark.parametrize("speeds, temperature, wear, temperature_range", [
    ([33.68, 38.68, 43.68], 40.0, 35.0, (30.0, 50.0)),
    ([35.84, 40.84], 44.0, 12.0, (30.0, 50.0)),
    ([40.84], 36.0, 30.0, (30.0, 50.0)),
    (DEFAULT_SPEEDS, 55.0, 10.0, (30.0, 80.0)),
])
def test_grid_summary_matches_a_brute_force_likelihood(speeds, temperature, wear, temperature_range):
    """Estimate, std, upper bound and flag against a direct evaluation on a 4× finer grid: agree
    within the coarser grid's resolution (wear step 0.5, temperature step ≤ 0.25 °C)."""
    rng = np.random.default_rng(3)
    tau = friction_magnitude(speeds, 0.47, temperature, wear) + rng.normal(0.0, SIGMA, len(speeds))
    result = WearEstimator(method="marginal", temperature_range=temperature_range).estimate(
        speeds, tau, 0.5, LOAD_STD)
    mode, std, upper, identifiable = brute_force_posterior(speeds, tau, 0.5, LOAD_STD, temperature_range)
    assert result.estimate == pytest.approx(mode, abs=0.3)
    assert result.std == pytest.approx(std, rel=0.02)
    assert result.upper_95 == pytest.approx(upper, abs=0.3)
    assert result.identifiable == identifiable


@settings(max_examples=25, deadline=None)
@given(temperature=st.floats(30.5, 49.5), wear=st.floats(15.0, 70.0), n_speeds=st.sampled_from([3, 12]))
def test_noise_free_data_give_the_true_wear_and_temperature(estimator, temperature, wear, n_speeds):
    # Below ϖ ≈ 15 the wear term is not identifiable with 3 speeds: at ϖ = 5, ξ = 33.6 °C a fit with
    # ϖ = 0 and a shifted ξ leaves a residual far below the solver tolerance (found by hypothesis in CI).
    speeds = DEFAULT_SPEEDS if n_speeds == 12 else [20.0, 45.0, 90.0]
    tau = friction_magnitude(speeds, LOAD_MEAN, temperature, wear)
    result = estimator.estimate(speeds, tau, LOAD_MEAN, LOAD_STD)
    assert result.ok and result.n_points == len(speeds)
    assert result.estimate == pytest.approx(wear, abs=1e-3)
    assert result.temperature == pytest.approx(temperature, abs=1e-3)
    assert 0.0 < result.std < math.inf
    assert result.upper_95 >= result.estimate


def test_single_speed_estimate_has_no_temperature(estimator, designs):
    speed = designs[1]
    tau = friction_magnitude(speed, LOAD_MEAN, 40.0, 35.0)
    result = estimator.estimate(speed, tau, LOAD_MEAN, LOAD_STD)
    assert result.ok and result.temperature is None and result.n_points == 1
    # The datum sits at the centre of the temperature range: the marginal ML is close to the truth
    # (within a fraction of its own standard deviation).
    assert abs(result.estimate - 35.0) < 0.5 * result.std
    assert result.estimate < result.upper_95 < 35.0 + 4 * result.std


def test_friction_stderr_widens_the_reported_std(estimator):
    speeds = [20.0, 45.0, 90.0]
    tau = friction_magnitude(speeds, LOAD_MEAN, 38.0, 30.0)
    plain = estimator.estimate(speeds, tau, LOAD_MEAN, LOAD_STD)
    noisy = estimator.estimate(speeds, tau, LOAD_MEAN, LOAD_STD, friction_stderr=[4e-3] * 3)
    assert noisy.std > plain.std
    assert noisy.upper_95 > plain.upper_95


def test_estimate_is_deterministic_and_record_is_json(estimator):
    rng = np.random.default_rng(5)
    speeds = [20.0, 45.0, 90.0]
    tau = friction_magnitude(speeds, 0.45, 36.0, 20.0) + rng.normal(0, SIGMA, 3)
    first = estimator.estimate(speeds, tau, LOAD_MEAN, LOAD_STD)
    assert first == estimator.estimate(speeds, tau, LOAD_MEAN, LOAD_STD)
    record = json.loads(json.dumps(first.to_record(), allow_nan=False))
    assert set(record) == RECORD_KEYS
    assert isinstance(record["identifiable"], bool) and record["upper_95"] >= record["estimate"]


def test_healthy_joint_gets_an_upper_bound_not_a_huge_std(marginal_estimator, designs):
    """The issue's "wear 3.2 ± >100": noise-free data of an unworn joint at the design speeds give a
    small estimate, a std of a few units (not the exploding local CRLB), identifiable = False and an
    upper bound below the critical level 35."""
    speeds = designs[3]
    result = marginal_estimator.estimate(speeds, friction_magnitude(speeds, LOAD_MEAN, 40.0, 0.0),
                                         LOAD_MEAN, LOAD_STD)
    assert crlb_wear(speeds, 40.0, 1e-6, LOAD_MEAN, LOAD_STD) > 1e4
    assert result.ok and not result.identifiable
    assert result.std < 10.0
    assert result.estimate < result.upper_95 < 35.0
    assert result.to_record()["identifiable"] is False


# --------------------------------------------------------------------------------- bad data
@pytest.mark.parametrize("speeds, friction, reason", [
    ([], [], "no friction data"),
    ([10.0, 20.0], [0.05, float("nan")], "non-finite datum"),
    ([10.0, float("inf")], [0.05, 0.06], "non-finite datum"),
    ([10.0, 20.0], [0.05], "length mismatch"),
    ([0.0, 20.0], [0.05, 0.06], "zero speed"),
    (["a", 20.0], [0.05, 0.06], "non-numeric input"),
])
def test_bad_data_give_a_reason_not_an_exception(estimator, speeds, friction, reason):
    result = estimator.estimate(speeds, friction, LOAD_MEAN, LOAD_STD)
    assert not result.ok and result.reason.startswith(reason)
    assert math.isnan(result.estimate) and math.isnan(result.upper_95) and not result.identifiable
    record = json.loads(json.dumps(result.to_record(), allow_nan=False))
    assert record["upper_95"] is None and record["identifiable"] is False


finite_or_not = st.one_of(st.floats(allow_nan=True, allow_infinity=True), st.floats(-1.0, 1.0))


@settings(max_examples=60, deadline=None)
@given(speeds=st.lists(st.one_of(st.floats(-300, 300), finite_or_not), max_size=6),
       friction=st.lists(finite_or_not, max_size=6),
       load=st.tuples(finite_or_not, finite_or_not),
       with_stderr=st.booleans(),
       method=st.sampled_from(["joint", "marginal"]))
def test_estimator_never_raises_and_respects_the_constraints(speeds, friction, load, with_stderr, method):
    estimator = WearEstimator(method=method)
    stderr = [1e-3] * len(friction) if with_stderr else None
    result = estimator.estimate(speeds, friction, load[0], load[1], friction_stderr=stderr)
    assert isinstance(result, WearEstimate)
    json.dumps(result.to_record(), allow_nan=False)
    if result.ok:
        assert 0.0 <= result.estimate <= result.upper_95 <= estimator.wear_max
        assert 0.0 <= result.std < math.inf
        if result.temperature is not None:
            assert 30.0 <= result.temperature <= 50.0
    else:
        assert result.reason


def test_invalid_configuration_is_refused():
    with pytest.raises(ValueError, match="temperature_range"):
        WearEstimator(temperature_range=(50.0, 30.0))
    with pytest.raises(ValueError, match="noise_std"):
        WearEstimator(noise_std=0.0)


# ------------------------------------------------------------------------------- Monte Carlo
DESIGN_RUNS = 600


@pytest.mark.slow
@pytest.mark.parametrize("n_speeds", [2, 3, 4])
def test_design_point_variance_bias_and_std_meet_the_targets(marginal_estimator, designs, n_speeds):
    """At ξ = 40 °C, ϖ = 35 and the designed speeds (the issue's complaint), over DESIGN_RUNS cycles:

    * variance ≤ 1.25 × design CRLB: s²/CRLB ≤ 1.25·q₀.₉₉₉₅ (q: quantiles of χ²(R−1)/(R−1));
    * |bias| ≤ 2: |mean − 35| ≤ 2 + 3.29·s/√R;
    * published std within 20 % of the spread: RMS(std)/s inside [0.8/√q₀.₉₉₉₅, 1.2/√q₀.₀₀₀₅];
    * upper_95 covers ϖ in ≥ 95 % of the cycles (one-sided 0.1 % binomial margin).
    """
    speeds = designs[n_speeds]
    tau, mu = simulate_cycles(speeds, 40.0, 35.0, DESIGN_RUNS, seed=100 + n_speeds)
    results = run_estimates(marginal_estimator, speeds, tau, mu)
    est, std, upper = field(results, "estimate"), field(results, "std"), field(results, "upper_95")
    spread = est.std(ddof=1)
    q_low, q_high = chi2_band(DESIGN_RUNS)
    crlb = crlb_wear(speeds, 40.0, 35.0, LOAD_MEAN, LOAD_STD)
    assert spread ** 2 / crlb <= 1.25 * q_high
    assert abs(est.mean() - 35.0) <= 2.0 + Z_999 * spread / math.sqrt(DESIGN_RUNS)
    ratio = math.sqrt(np.mean(std ** 2)) / spread
    assert 0.8 / math.sqrt(q_high) <= ratio <= 1.2 / math.sqrt(q_low)
    assert np.mean(35.0 <= upper) >= coverage_floor(0.95, DESIGN_RUNS)


SWEEP_RUNS = 300


@pytest.mark.slow
@pytest.mark.parametrize("temperature", [30.0, 50.0])
def test_bounds_on_temperature_keep_the_variance_low_off_the_design_temperature(
        marginal_estimator, designs, temperature):
    """At the ends of the site range the local CRLB of the 3-point design is 300–1000, but the box
    ξ ∈ [30, 50] keeps the spread at the design-point level: s² ≤ 1.5 × the design CRLB (19.7) and
    |bias| ≤ 4 (≤ 0.9 std; measured +2.2 / +3.1 in the full study), std honest within 20 %."""
    speeds = designs[3]
    assert crlb_wear(speeds, temperature, 35.0, LOAD_MEAN, LOAD_STD) > 250.0
    tau, mu = simulate_cycles(speeds, temperature, 35.0, SWEEP_RUNS, seed=200 + int(temperature))
    results = run_estimates(marginal_estimator, speeds, tau, mu)
    est, std = field(results, "estimate"), field(results, "std")
    spread = est.std(ddof=1)
    q_low, q_high = chi2_band(SWEEP_RUNS)
    assert spread ** 2 / crlb_wear(speeds, 40.0, 35.0, LOAD_MEAN, LOAD_STD) <= 1.5 * q_high
    assert abs(est.mean() - 35.0) <= 4.0 + Z_999 * spread / math.sqrt(SWEEP_RUNS)
    ratio = math.sqrt(np.mean(std ** 2)) / spread
    assert 0.8 / math.sqrt(q_high) <= ratio <= 1.2 / math.sqrt(q_low)


BOUND_RUNS = 400


@pytest.mark.slow
@pytest.mark.parametrize("speeds_name, temperature_range, temperature", [
    ("design3", (30.0, 50.0), 35.0), ("design3", (30.0, 50.0), 40.0), ("design3", (30.0, 50.0), 50.0),
    ("default12", (30.0, 80.0), 40.0), ("default12", (30.0, 80.0), 60.0),
])
def test_upper_bound_covers_low_wear_and_stays_below_the_critical_level(
        designs, speeds_name, temperature_range, temperature):
    """Both sides of the one-sided bound near ϖ = 0, where ϖ is not identifiable:

    * coverage P(ϖ ≤ upper_95) ≥ 0.95 at ϖ = 0 (trivially 1: any bound ≥ 0 covers 0) and at ϖ = 5
      (measured 1.00: at the design speeds ϖ = 5 is indistinguishable from 0, so a valid bound must
      lie above it) — checked with a one-sided 0.1 % binomial margin;
    * not vacuous: at ϖ = 0 the median bound stays below the critical level 35 and the estimate is
      flagged not identifiable in ≥ 90 % of the cycles (measured 96–100 %; at ϖ = 35, 3 speeds,
      40 °C it is identifiable in 98 %).
    """
    speeds = designs[3] if speeds_name == "design3" else DEFAULT_SPEEDS
    est = WearEstimator(method="marginal", temperature_range=temperature_range)
    for wear in (0.0, 5.0):
        tau, mu = simulate_cycles(speeds, temperature, wear, BOUND_RUNS, seed=300 + int(temperature + wear))
        results = run_estimates(est, speeds, tau, mu)
        upper = field(results, "upper_95")
        assert np.mean(wear <= upper) >= coverage_floor(0.95, BOUND_RUNS)
        if wear == 0.0:
            assert np.median(upper) < 35.0
            assert np.mean(field(results, "identifiable")) <= 0.10


@pytest.mark.slow
def test_upper_bound_coverage_at_identifiable_wear(marginal_estimator, designs):
    """Where ϖ is identifiable the bound is a real 95 % bound: at ϖ = 20 and 35, 3 design speeds,
    ξ = 40 °C (the fold, where the estimates are biased low and the nominal one-sided 1.645² level
    covered only ≈ 0.93) the coverage is ≥ 0.95 within the binomial margin, and ≤ 0.995 (not vacuous:
    measured 0.97–0.98)."""
    speeds = designs[3]
    for wear in (20.0, 35.0):
        tau, mu = simulate_cycles(speeds, 40.0, wear, BOUND_RUNS, seed=400 + int(wear))
        coverage = np.mean(wear <= field(run_estimates(marginal_estimator, speeds, tau, mu), "upper_95"))
        assert coverage_floor(0.95, BOUND_RUNS) <= coverage <= 0.995


RUNS = 100


@pytest.mark.slow
@pytest.mark.parametrize("wear", [20.0, 35.0])
def test_joint_estimate_is_biased_low_at_the_design_speeds(estimator, marginal_estimator, designs, wear):
    """Documents the finding of tools/studies/mc_wear_study.py: at the design speeds (clustered where
    ∂τf/∂ξ ≈ 0 at 40 °C, a fold of τ0 in ξ) the joint ML of §3 is biased low, the marginal one
    less. Paired on the same cycles: the mean difference joint − marginal is negative beyond its own
    3.29 standard errors."""
    speeds = designs[2]
    tau, mu = simulate_cycles(speeds, 40.0, wear, RUNS, seed=500 + int(wear))
    joint = field(run_estimates(estimator, speeds, tau, mu), "estimate")
    marginal = field(run_estimates(marginal_estimator, speeds, tau, mu), "estimate")
    diff = joint - marginal
    assert diff.mean() < -Z_999 * diff.std(ddof=1) / math.sqrt(RUNS)


@pytest.mark.slow
def test_design_speeds_beat_badly_chosen_speeds(marginal_estimator, designs):
    """Variance at 82/133 rad/s exceeds the design's by an F-test at 0.1 % (same cycles' conditions)."""
    tau_design, mu = simulate_cycles(designs[2], 40.0, 35.0, RUNS, seed=7)
    tau_bad, mu_bad = simulate_cycles(BAD_SPEEDS, 40.0, 35.0, RUNS, seed=7)
    var_design = field(run_estimates(marginal_estimator, designs[2], tau_design, mu), "estimate").var(ddof=1)
    var_bad = field(run_estimates(marginal_estimator, BAD_SPEEDS, tau_bad, mu_bad), "estimate").var(ddof=1)
    assert var_bad / var_design > stats.f.ppf(0.999, RUNS - 1, RUNS - 1)


@pytest.mark.slow
def test_no_wear_stays_low_and_wear_shows(marginal_estimator, designs):
    """Both sides: at ϖ = 0 the estimates stay below the critical level 35 in all but a few cycles,
    at ϖ = 50 above it in all but a few, and identifiable in all but a few. A wrong side needs an
    error of ≥ 15 wear units, ≥ 2.7 standard deviations (≈ 5.5 at ϖ = 0, 4.5 at ϖ = 50, N = 3),
    one-sided p ≤ 0.35 % per cycle; more than 5 of 100 wrong-side cycles then has binomial
    probability < 1e-4."""
    speeds = designs[3]
    healthy = run_estimates(marginal_estimator, speeds, *simulate_cycles(speeds, 40.0, 0.0, RUNS, seed=11))
    worn = run_estimates(marginal_estimator, speeds, *simulate_cycles(speeds, 40.0, 50.0, RUNS, seed=12))
    assert np.all(field(healthy, "estimate") >= 0.0)
    assert np.sum(field(healthy, "estimate") >= 35.0) <= 5
    assert np.sum(field(worn, "estimate") < 35.0) <= 5
    assert np.sum(~field(worn, "identifiable").astype(bool)) <= 5


@pytest.mark.slow
@pytest.mark.parametrize("temperature", [32.0, 48.0])
def test_score_is_close_to_standard_normal_without_wear_at_any_temperature(marginal_estimator, temperature):
    """The detector's wear quantity (signed root of the likelihood ratio against ϖ = 0) has the same
    distribution on a healthy joint whether the lubricant is cold or warm, although wear is far less
    identifiable warm: 150 cycles of the 12 default speeds with a motor-temperature prior (σ 3 °C).
    Asymptotically N(0, 1); at these sample sizes the mean is measured at −0.02 … +0.37 and the std at
    0.93 … 0.94 (seed 1, 200 cycles). Bounds: the mean within 0.6 (the measured offset plus 3.3 standard
    errors of 0.08), the std within the 99.9 % χ² band of 150 samples around 1, widened by 10 %."""
    rng = np.random.default_rng(21)
    tau, load_estimate = simulate_cycles(DEFAULT_SPEEDS, temperature, 0.0, 150, seed=int(temperature))
    priors = temperature + rng.normal(0.0, 3.0, 150)
    score = np.array([marginal_estimator.estimate(DEFAULT_SPEEDS, row, mu, LOAD_STD,
                                                  temperature_prior=(float(p), 3.0)).score
                      for row, mu, p in zip(tau, load_estimate, priors)])
    low, high = chi2_band(150)
    assert np.all(np.isfinite(score))
    assert abs(score.mean()) <= 0.6
    assert 0.9 * low <= score.var(ddof=1) <= 1.1 * high


@pytest.mark.slow
@pytest.mark.parametrize("temperature", [32.0, 48.0])
def test_score_shows_critical_wear_cold_and_warm(marginal_estimator, temperature):
    """The other side: at the critical wear 35 the score exceeds 3 in all but a few cycles (measured:
    all at 32 °C, 96.5 % at 48 °C where wear is least identifiable; mean 7.4 and 4.8)."""
    rng = np.random.default_rng(22)
    tau, load_estimate = simulate_cycles(DEFAULT_SPEEDS, temperature, 35.0, 100, seed=100 + int(temperature))
    priors = temperature + rng.normal(0.0, 3.0, 100)
    score = np.array([marginal_estimator.estimate(DEFAULT_SPEEDS, row, mu, LOAD_STD,
                                                  temperature_prior=(float(p), 3.0)).score
                      for row, mu, p in zip(tau, load_estimate, priors)])
    assert np.sum(score > 3.0) >= 85


@pytest.fixture(scope="module")
def site_estimator() -> WearEstimator:
    """The agent's estimator: site range 30 … 80 °C (edge_monitor/defaults/agent.toml)."""
    return WearEstimator(method="marginal", temperature_range=(30.0, 80.0))


def flat_prior_scores(estimator: WearEstimator, wear: float, runs: int, seed: int) -> np.ndarray:
    """Scores of ``runs`` cycles at 44 °C without a temperature prior (a controller without one)."""
    tau, load_estimate = simulate_cycles(DEFAULT_SPEEDS, 44.0, wear, runs, seed=seed)
    return np.array([estimator.estimate(DEFAULT_SPEEDS, row, mu, LOAD_STD).score
                     for row, mu in zip(tau, load_estimate)])


def test_score_keeps_its_sign_on_a_worn_joint_without_temperature(site_estimator):
    """Without a temperature prior ξ is free over 30 … 80 °C, and the score's continuation below ϖ = 0,
    reached to −ϖmax, fitted a worn joint as negative wear with a warmer lubricant: the sign flipped on
    37 of 100 cycles at wear 25 (44 °C), 49 of 100 > 2. Bounded at −20 (the continuation's local job):
    measured 8 negative and 71 > 2 (seed 42; 2 and 70 with another). Bounds at p ≈ 0.05 and 0.7
    per cycle: > 15 negative or < 55 above 2 each have binomial probability < 10⁻³."""
    worn = flat_prior_scores(site_estimator, 25.0, 100, seed=42)
    assert np.sum(worn < 0.0) <= 15
    assert np.sum(worn > 2.0) >= 55


def test_bounded_continuation_keeps_a_healthy_joint_quiet(site_estimator):
    """The other side, same setting without wear: the score stays below 3 (measured: 0 of 150, max
    < 3, mean +0.52, variance 0.46; the detector learns its own nominal of these values). Bound: at most
    2 of 150 above 3 (a N(0, 1) score would have 0.2 expected)."""
    healthy = flat_prior_scores(site_estimator, 0.0, 150, seed=41)
    assert np.all(np.isfinite(healthy))
    assert np.sum(healthy > 3.0) <= 2
    assert abs(healthy.mean()) <= 1.0


def test_continuation_bound_applies_only_without_a_temperature_prior(site_estimator, monkeypatch):
    """With a motor-temperature prior the score is what it was before the bound (the agent's calibrated
    native path): the same values with the bound moved out of reach. On these 40 healthy cycles the
    best wear of 4 lies below −20 (measured), so a bound applied with the prior would change them."""
    tau, load_estimate = simulate_cycles(DEFAULT_SPEEDS, 44.0, 0.0, 40, seed=43)

    def scores() -> list[float]:
        return [site_estimator.estimate(DEFAULT_SPEEDS, row, mu, LOAD_STD, temperature_prior=(44.0, 3.0)).score
                for row, mu in zip(tau, load_estimate)]

    bounded = scores()
    monkeypatch.setattr("edge_monitor.features.wear_estimation._FLAT_PRIOR_CONTINUATION", 1e9)
    assert scores() == bounded
