"""One-sided GLR with a drift allowance and winsorised observations: the null box, its calibration at
the boundary, and both sides of every claim (quiet where H0 holds, alarms where it does not)."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest
from learned_units import learned_detector

from edge_monitor.stats.densities import fit_gaussian, fit_gce
from edge_monitor.stats.glr import WindowedGLR
from edge_monitor.stats.glr_batch import BatchWindowedGLR, MixtureBatch, clip_range, null_box
from edge_monitor.stats.sequential_detector import DetectorConfig, DetectorConfigError, SequentialDetector


def _nominal(seed: int, n: int = 60, d: int = 1) -> np.ndarray:
    return np.random.default_rng(seed).normal(size=(n, d))


def _refused(table: str, cases: tuple) -> None:
    """Each (value, message) of ``cases`` as ``[decision.<table>]`` is a ConfigError matching the message."""
    from edge_monitor.config import ConfigError, config_from_mapping

    for bad, key in cases:
        with pytest.raises(ConfigError, match=key):
            config_from_mapping({"decision": {table: bad}})


def test_null_box_and_clip_range_follow_the_nominal_spread() -> None:
    values = _nominal(0, d=2) * [1.0, 4.0] + [0.0, 10.0]
    std = values.std(axis=0, ddof=1)
    lower, upper = null_box(values, "increase", 0.5)
    assert np.all(lower == -np.inf) and np.allclose(upper, 0.5 * std)
    lower, upper = null_box(values, "both", 1.0)
    assert np.allclose(lower, -std) and np.allclose(upper, std)
    assert [b.tolist() for b in null_box(values)] == [[0.0, 0.0], [0.0, 0.0]]
    lo, hi = clip_range(values, 3.0)
    assert np.allclose(lo, values.mean(axis=0) - 3 * std) and np.allclose(hi, values.mean(axis=0) + 3 * std)
    assert [b.tolist() for b in clip_range(values, 0.0)] == [[-math.inf] * 2, [math.inf] * 2]
    with pytest.raises(ValueError, match="direction"):
        null_box(values, "decrease")


def test_zero_box_is_the_plain_two_sided_recursion_bit_for_bit() -> None:
    rng = np.random.default_rng(1)
    mixtures = MixtureBatch([fit_gce(rng.normal(size=(60, 1)))])
    plain = BatchWindowedGLR(mixtures, 20)
    boxed = BatchWindowedGLR(mixtures, 20, null_box=(np.zeros(1), np.zeros(1)), clip=(-np.inf, np.inf))
    for y in np.r_[rng.normal(size=50), rng.normal(size=30) + 1.5]:
        assert boxed.update([[y]])[0] == plain.update([[y]])[0]


@pytest.mark.parametrize("mode", ["exact", "recursive"])
def test_box_statistic_matches_the_composite_null_likelihood_ratio(mode: str) -> None:
    """For one Gaussian the composite-null GLR of a candidate with estimate Δ̂ is
    Σ log p0(y − Δ̂) − log p0(y − clip(Δ̂, lower, upper)); checked against scipy at the end of a window."""
    from scipy import stats

    rng = np.random.default_rng(2)
    density = fit_gaussian(rng.normal(size=(200, 1)))
    mu, sd = float(density.means[0, 0]), math.sqrt(float(density.cov[0, 0]))
    upper = 0.5 * sd
    glr = BatchWindowedGLR(MixtureBatch([density]), window=6, mode="exact",
                           null_box=(np.full(1, -np.inf), np.full(1, upper)))
    y = rng.normal(size=12) + 1.5
    for v in y:
        stat = glr.update([[v]])[0]
    best = int(glr.best[0])
    delta = float(glr.delta[0, best, 0])
    start = int(glr.times[best])
    segment = y[start:]
    expected = np.sum(stats.norm.logpdf(segment - delta, mu, sd) - stats.norm.logpdf(segment - min(delta, upper), mu, sd))
    assert stat == pytest.approx(max(expected, 0.0), rel=1e-9, abs=1e-9)


def test_one_sided_detector_ignores_a_decrease_and_alarms_on_an_increase() -> None:
    """Both sides with one threshold (Pf 1e-6 for a window of 50): a −3σ shift is nominal for a test of
    increase, +3σ is not; the two-sided test alarms on both."""
    nominal = _nominal(3, n=300)
    density = fit_gce(nominal)
    rng = np.random.default_rng(4)
    stream = rng.normal(size=60)

    def alarms(shift: float, direction: str) -> bool:
        glr = WindowedGLR(density, window=50, pf=1e-6, mode="recursive", null_box=null_box(nominal, direction))
        return any(glr.update(v).alarm for v in stream + shift)

    assert not alarms(-3.0, "increase") and alarms(3.0, "increase")
    assert alarms(-3.0, "both") and alarms(3.0, "both")
    assert not alarms(0.0, "increase") and not alarms(0.0, "both")


def test_allowance_absorbs_drifts_inside_it_and_not_beyond() -> None:
    """Allowance 1σ: a sustained +0.8σ shift stays quiet, a +3σ shift alarms; without the allowance the
    +0.8σ shift alarms (same threshold, same data, 400 cycles)."""
    nominal = _nominal(5, n=400)
    density = fit_gaussian(nominal)
    stream = np.random.default_rng(6).normal(size=400)

    def alarms(shift: float, allowance: float) -> bool:
        glr = WindowedGLR(density, window=100, pf=1e-6, mode="recursive",
                          null_box=null_box(nominal, "increase", allowance))
        return any(glr.update(v).alarm for v in stream + shift)

    assert not alarms(0.8, 1.0) and alarms(3.0, 1.0)
    assert alarms(0.8, 0.0)


def test_winsorising_stops_one_outlier_from_alarming_but_not_a_shift() -> None:
    nominal = _nominal(7)
    density = fit_gce(nominal)
    stream = np.random.default_rng(8).normal(size=80)
    spike = stream.copy()
    spike[40] = 40.0                                   # one wild value (a glitch, not wear)

    def alarms(values: np.ndarray, clip_sigma: float) -> bool:
        glr = WindowedGLR(density, window=50, pf=1e-6, mode="recursive", null_box=null_box(nominal, "increase"),
                          clip=clip_range(nominal, clip_sigma))
        return any(glr.update(v).alarm for v in values)

    assert alarms(spike, 0.0) and not alarms(spike, 3.0)
    assert alarms(stream + 2.5, 3.0)


def test_box_and_clip_survive_the_state_round_trip_through_json() -> None:
    nominal = _nominal(9)
    glr = WindowedGLR(fit_gce(nominal), window=20, mode="recursive", null_box=null_box(nominal, "increase", 0.5),
                      clip=clip_range(nominal, 3.0))
    rng = np.random.default_rng(10)
    for v in rng.normal(size=30):
        glr.update(v)
    text = json.dumps(glr.state_dict(), allow_nan=False)   # ±inf must not leak into JSON
    back = WindowedGLR.from_state(json.loads(text))
    for v in rng.normal(size=30) + 1.0:
        assert back.update(v) == glr.update(v)


def test_miss_probability_counts_only_the_shift_beyond_the_allowance() -> None:
    nominal = _nominal(11, n=400)
    density = fit_gaussian(nominal)
    std = float(nominal.std(ddof=1))
    stream = np.random.default_rng(12).normal(size=60) + 1.0
    last = {}
    for allowance in (0.0, 0.9):
        glr = WindowedGLR(density, window=100, pf=1e-6, mode="recursive",
                          null_box=null_box(nominal, "increase", allowance))
        for v in stream:
            last[allowance] = glr.update(v)
    assert last[0.0].delta[0] == pytest.approx(1.0 * std, abs=0.4)
    assert last[0.9].miss_probability > last[0.0].miss_probability      # little shift left beyond 0.9σ


@pytest.mark.parametrize("kwargs, match", [({"direction": "up"}, "direction"), ({"allowance": -0.1}, "allowance"),
                                           ({"allowance": 6}, "allowance"), ({"clip_sigma": 0.5}, "clip_sigma")])
def test_bad_direction_allowance_or_clip_is_a_clear_error(kwargs: dict, match: str) -> None:
    with pytest.raises(DetectorConfigError, match=match):
        DetectorConfig(**kwargs)


@pytest.mark.slow
def test_calibration_at_the_allowance_boundary_holds_the_run_length_there_and_exceeds_it_inside() -> None:
    """Allowance 0.5σ, ARL0 = 100 cycles, 40 learned nominals (60 values each), each run for 600
    cycles with every false alarm acknowledged (the statistic restarts): total cycles over total
    alarms is then the mean false-alarm rate over the nominals, the fleet's rate the calibration is for.
    Streams shifted by the allowance (+0.5σ, the least favourable nominal) must give a run length within
    0.5 … 2.5 × ARL0 (≈ 240 alarms expected: the Poisson error is ±7 %, the rest is the spread of the
    40 nominals' rates, coefficient of variation ≤ 2.3 → standard error ≤ 0.37 of the mean rate);
    unshifted streams must run at least 2 × ARL0 (the margin the allowance buys); a +2.5σ shift (2σ
    beyond the allowance) is found within 100 cycles in ≥ 36 of 40 runs."""
    rng = np.random.default_rng(13)
    arl0, cap, runs = 100.0, 600, 40
    config = DetectorConfig(arl0=arl0, direction="increase", allowance=0.5, clip_sigma=3.0,
                            calibration_draws=32, calibration_steps=1200)
    alarms = {0.0: 0, 0.5: 0}
    detected = 0
    for _ in range(runs):
        learned = SequentialDetector(config)
        for i, v in enumerate(rng.normal(size=60)):
            learned.update(v, i)
        state = learned.state_dict()
        for shift in alarms:
            det = SequentialDetector.from_state(config, state)
            for t in range(1, cap + 1):
                if det.update(rng.normal() + shift, 60 + t).alarm:
                    alarms[shift] += 1
                    det.acknowledge()
        det = SequentialDetector.from_state(config, state)
        detected += any(det.update(rng.normal() + 2.5, 60 + t).alarm for t in range(1, 101))
    measured = {shift: runs * cap / max(n, 1) for shift, n in alarms.items()}
    print(f"measured ARL at the boundary {measured[0.5]:.0f}, at 0 {measured[0.0]:.0f} (target {arl0:.0f}); "
          f"detected {detected}/{runs}")
    assert 0.5 * arl0 <= measured[0.5] <= 2.5 * arl0, measured
    assert measured[0.0] >= 2.0 * arl0, measured
    assert detected >= 36, detected


def test_calibrating_on_the_learned_nominal_gives_a_lower_threshold_than_at_the_boundary() -> None:
    """Studies may calibrate on the learned nominal (``at="nominal"``): with an allowance the
    threshold is lower than the agent's boundary calibration; without one both are the same
    simulation; an unknown ``at`` is a clear error."""
    from edge_monitor.stats.calibration import CalibrationBudget, calibrate

    nominal = np.random.default_rng(5).normal(size=(60, 1))
    budget = CalibrationBudget(draws=16, max_steps=600)

    def h(at: str, allowance: float) -> float:
        return calibrate(nominal, "gauss", 50, 200.0, budget=budget, direction="increase", allowance=allowance,
                         clip_sigma=3.0, at=at).threshold

    assert h("nominal", 0.75) < h("boundary", 0.75)
    assert h("nominal", 0.0) == h("boundary", 0.0)
    with pytest.raises(ValueError, match="at ="):
        h("middle", 0.75)


def test_healthy_drift_shifts_are_a_stratified_fleet_around_the_stated_drift() -> None:
    """``at="healthy_drift"``: draw b sits at (mean + sd·z_b)·spread with z_b the normal quantiles at
    (b + ½)/B (their mean is 0 by symmetry, their std → 1), one z_b for every dimension; "boundary" puts
    every draw at the allowance, "nominal" at 0."""
    from edge_monitor.stats.calibration import stream_shifts

    spread = np.array([2.0, 0.5])
    shifts = stream_shifts(spread, 64, "healthy_drift", drift_mean=(0.3, 0.1), drift_sd=(0.4, 0.2),
                           rng=np.random.default_rng(1))
    assert shifts.shape == (64, 2)
    np.testing.assert_allclose(shifts.mean(axis=0), [0.6, 0.05], atol=1e-12)
    np.testing.assert_allclose(shifts.std(axis=0), [0.8, 0.1], rtol=0.05)
    z = (shifts / spread - [0.3, 0.1]) / [0.4, 0.2]
    np.testing.assert_allclose(z[:, 0], z[:, 1], atol=1e-12)           # the joint's quantities drift together
    np.testing.assert_array_equal(stream_shifts(spread, 4, "boundary", allowance=0.75), np.tile([1.5, 0.375], (4, 1)))
    np.testing.assert_array_equal(stream_shifts(spread, 4, "nominal", allowance=0.75), np.zeros((4, 2)))


def test_healthy_drift_calibration_reduces_to_the_nominal_and_boundary_ones_and_sits_between() -> None:
    """The drift stream has its own random numbers, so a healthy drift of exactly 0 is the nominal
    calibration and one of exactly the allowance (sd 0) the boundary one, bit for bit; a drift spread
    around a mean inside the allowance gives a threshold between the two; its record says where."""
    from edge_monitor.stats.calibration import CalibrationBudget, calibrate

    nominal = np.random.default_rng(5).normal(size=(60, 1))
    budget = CalibrationBudget(draws=16, max_steps=600)

    def cal(at: str, mean: float = 0.0, sd: float = 0.0):  # type: ignore[no-untyped-def]
        return calibrate(nominal, "gauss", 50, 200.0, budget=budget, direction="increase", allowance=0.75,
                         clip_sigma=3.0, at=at, drift_mean=(mean,), drift_sd=(sd,))

    assert cal("healthy_drift").threshold == cal("nominal").threshold
    assert cal("healthy_drift", 0.75).threshold == cal("boundary").threshold
    between = cal("healthy_drift", 0.3, 0.3)
    assert cal("nominal").threshold < between.threshold < cal("boundary").threshold
    assert between.at == "healthy_drift"


@pytest.mark.parametrize("kwargs, match", [
    ({"calibrate_at": "middle"}, "calibrate_at"),
    ({"calibrate_at": "healthy_drift"}, "drift_mean"),
    ({"calibrate_at": "healthy_drift", "drift_mean": (0.1,), "drift_sd": (-1.0,)}, "drift_sd"),
])
def test_bad_calibration_placement_is_a_clear_error(kwargs: dict, match: str) -> None:
    with pytest.raises(DetectorConfigError, match=match):
        DetectorConfig(**kwargs)


def test_healthy_drift_settings_reach_each_detector_and_survive_the_state_round_trip() -> None:
    """``decision.healthy_drift`` (input → [mean, sd]) is merged over the defaults, validated with the
    key named, handed to each detector per input, and a detector saved with it restores with it."""
    from edge_monitor.config import config_from_mapping
    from edge_monitor.pipeline.detectors import HEALTHY_DRIFT

    cfg = config_from_mapping({"decision": {"calibrate_at": "healthy_drift",
                                            "healthy_drift": {"kl_raw": [0.5, 0.25]}}}).decision
    assert cfg.healthy_drift == {**HEALTHY_DRIFT, "kl_raw": (0.5, 0.25)}
    joint = cfg.detector_config("joint")
    assert joint.drift_mean == (HEALTHY_DRIFT["wear_score"][0], 0.5, HEALTHY_DRIFT["kl_weighted"][0])
    assert joint.drift_sd[1] == 0.25
    _refused("healthy_drift", (({"kl_raw": [0.1]}, "decision.healthy_drift.kl_raw"), ({"torque": [0, 1]}, "torque"),
                               ({"wear_score": [0.1, -0.2]}, "wear_score"), ([1, 2], "expected a table")))
    config = DetectorConfig(arl0=100.0, direction="increase", allowance=0.75, calibrate_at="healthy_drift",
                            drift_mean=(0.3,), drift_sd=(0.3,), calibration_draws=16, calibration_steps=600)
    det, decision = learned_detector(config, seed=2)
    assert decision.calibration is not None and decision.calibration["at"] == "healthy_drift"
    state = json.loads(json.dumps(det.state_dict()))
    restored = SequentialDetector.from_state(config, state)
    assert restored.threshold == det.threshold and math.isfinite(det.threshold)


def test_a_warm_up_law_reaches_the_scalar_warm_up_detectors_only_and_a_saved_nominal_is_recalibrated() -> None:
    """``decision.warm_up_law`` (input → [mean, sd, spread, spread sd(, wander)]) reaches each scalar detector's warm-up
    calibration (its mean law as the drift, its spread law beside it), not the joint vector (which keeps
    ``healthy_drift``) nor a steady calibration; [] gives the input back to ``healthy_drift``; bad laws are
    refused with the key named; a detector saved before the law re-derives its threshold for it (its
    nominal is kept: the law is where the calibration simulates, not what the detector learned)."""
    from edge_monitor.config import config_from_mapping
    from edge_monitor.pipeline.healthy_drift import HEALTHY_DRIFT, WARM_UP_LAW

    cfg = config_from_mapping({"decision": {"warm_up_law": {"kl_raw": [-0.2, 0.1, 0.9, 0.1], "wear_score": []}}})
    decision = cfg.decision
    kl_raw = decision.detector_config("kl_raw")
    assert (kl_raw.drift_mean, kl_raw.drift_sd, kl_raw.spread_mean, kl_raw.spread_sd) == ((-0.2,), (0.1,), (0.9,), (0.1,))
    assert kl_raw.calibration("steady")["spread_mean"] == () and kl_raw.calibration("warm-up")["spread_sd"] == (0.1,)
    wear = decision.detector_config("wear")
    assert (wear.drift_mean, wear.drift_sd, wear.spread_mean) == ((HEALTHY_DRIFT["wear_score"][0],),
                                                                  (HEALTHY_DRIFT["wear_score"][1],), ())
    joint = decision.detector_config("joint")
    assert joint.spread_mean == () and joint.drift_mean == tuple(HEALTHY_DRIFT[q][0] for q in HEALTHY_DRIFT)
    assert kl_raw.warm_up_wander == () and kl_raw.calibration("warm-up")["wander"] == ()
    shipped = decision.detector_config("kl_weighted")
    assert shipped.spread_mean == (WARM_UP_LAW["kl_weighted"][2],)
    assert shipped.calibration("warm-up")["wander"] == (WARM_UP_LAW["kl_weighted"][4],) == (0.09,)
    assert shipped.calibration("steady")["wander"] == (decision.steady_wander["kl_weighted"],)
    wandering = config_from_mapping({"decision": {"warm_up_law": {"kl_raw": [-0.2, 0.1, 0.9, 0.1, 0.2]}}}).decision
    assert wandering.detector_config("kl_raw").calibration("warm-up")["wander"] == (0.2,)
    _refused("warm_up_law", (({"kl_raw": [0.1, 0.1, 0.9]}, "decision.warm_up_law.kl_raw"), ({"torque": []}, "torque"),
                             ({"kl_raw": [0.0, 0.1, 0.0, 0.1]}, "kl_raw"), ({"kl_raw": [0.0, -0.1, 1.0, 0.1]}, "kl_raw"),
                             ({"kl_raw": [0.0, 0.1, 1.0, 0.1, 1.0]}, "kl_raw")))
    before = DetectorConfig(arl0=200.0, direction="increase", allowance=0.75, calibrate_at="healthy_drift",
                            drift_mean=(0.0,), drift_sd=(0.08,), calibration_draws=16, calibration_steps=600)
    det, _ = learned_detector(before, seed=3)
    with_law = DetectorConfig(**{**before.__dict__, "drift_mean": (-0.126,), "drift_sd": (0.047,),
                                 "spread_mean": (0.908,), "spread_sd": (0.084,)})
    restored = SequentialDetector.from_state(with_law, json.loads(json.dumps(det.state_dict())))
    restored.update(0.0, 60)
    assert restored.state == "monitoring" and restored.calibrated_job is not None
    assert restored.calibrated_job.spread_mean == (0.908,)
    assert restored.threshold is not None and det.threshold is not None and restored.threshold < det.threshold


def test_a_fleet_counts_the_mean_rate_of_its_learned_nominals_not_the_pooled_first_passages() -> None:
    """Two learned nominals of 4 simulated detectors each: one group alarms at cycle 10, the other never
    within 1000. A group's rate is (e − 1)/X = 3/40 (the small-sample correction of 4/40 for
    exponential passages) and the fleet's the mean of the groups', ½·(3/40 + 0), so its mean run length
    is 80/3 cycles; pooling first passages would say (4·10 + 4·1000) / 4 = 1010."""
    from edge_monitor.stats.calibration import fleet_run_lengths, mean_run_lengths

    statistics = np.zeros((8, 1000))
    statistics[4:, 9:] = 5.0
    fleet, events = fleet_run_lengths(statistics, np.array([1.0, 6.0]), groups=2)
    assert fleet[0] == pytest.approx(80 / 3) and events[0] == 4
    assert np.isinf(fleet[1]) and events[1] == 0
    assert mean_run_lengths(statistics, np.array([1.0]))[0][0] == 1010.0


def test_no_fingerprint_names_where_the_calibration_simulates() -> None:
    """Neither the decision nor a detector fingerprint names the calibration point or the drifts: they are
    not learned (a changed one re-derives the saved nominal's threshold, tests/test_sequential_detector.py),
    and states saved before these settings existed match."""
    from edge_monitor.pipeline.detectors import DecisionConfig

    for config in (DecisionConfig(), DecisionConfig(calibrate_at="healthy_drift", steady_calibrate_at="nominal")):
        assert not {"calibrate_at", "healthy_drift", "steady_calibrate_at", "steady_drift", "steady_drift_joint",
                    "steady_wander"} & set(config.fingerprint())
        for quantity in ("kl_raw", "joint"):
            assert not {"calibrate_at", "drift_mean", "drift_sd", "steady_at", "steady_drift_mean",
                        "steady_drift_sd", "steady_wander"} & set(config.detector_config(quantity).fingerprint())
    assert DecisionConfig().fingerprint() == DecisionConfig(calibrate_at="healthy_drift").fingerprint()
