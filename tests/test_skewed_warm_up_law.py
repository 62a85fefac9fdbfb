"""The warm-up law's skew: a scalar warm-up detector's values whose upper tail is lighter (or heavier) than the
Gaussian's, simulated as skew-normal in the calibration (docs/DETECTION.md, "The warm-up stage")."""

from __future__ import annotations

import dataclasses
import json
import math
import sys
from pathlib import Path
from typing import Callable

import numpy as np
import pytest
from learned_units import delivered_in_learned_units, delivered_tolerance, learned_detector
from scipy.stats import skewnorm

from edge_monitor.stats.calibration import CalibrationBudget, CalibrationJob
from edge_monitor.stats.gaussian_calibration import GaussianBudget, GaussianSettings, threshold
from edge_monitor.stats.gaussian_fleet import StreamNoise, skew_normal_standard
from edge_monitor.stats.threshold_table import key

sys.path.insert(0, str(Path(__file__).resolve().parent.parent / "tools" / "studies"))

from temperature_law_study import share_above, tail_shape  # noqa: E402

WARM_UP = GaussianSettings(60, 100, 0.6, 1.0, "increase", 0.75, 3.0, "healthy_drift", drift_mean=(-0.141,),
                           drift_sd=(0.071,), spread_mean=(0.975,), spread_sd=(0.105,))
BUDGET = GaussianBudget(nominals=256, streams=4, steps=2000)
ALPHA = -1.74


def test_skew_normal_values_have_unit_variance_and_the_shapes_tail() -> None:
    """400 000 draws of shape −1.74: mean 0 and variance 1, skewness and share above 2 sd those of scipy's
    skew-normal of that shape; each within 4 standard errors (√(1/n), √(2/n), √(6/n), √(p(1 − p)/n))."""
    n = 400_000
    rng = np.random.default_rng(7)
    v = skew_normal_standard(ALPHA, rng.standard_normal(n), rng.standard_normal(n))
    mean, var, skew = (float(m) for m in skewnorm.stats(ALPHA, moments="mvs"))
    p = float(skewnorm.sf(mean + 2.0 * math.sqrt(var), ALPHA))
    assert abs(v.mean()) < 4 / math.sqrt(n) and abs(v.var() - 1.0) < 4 * math.sqrt(2 / n)
    assert abs(np.mean(v ** 3) - skew) < 4 * math.sqrt(6 / n) and skew < -0.3
    assert abs(np.mean(v > 2.0) - p) < 4 * math.sqrt(p * (1 - p) / n) and p < 0.018


def test_the_study_fits_the_shape_the_calibration_draws() -> None:
    """The calibration's stream (skew-normal iid part, 9 % Gaussian wander) puts above 2 sd the share the
    study's fit assumes for that shape (4 standard errors, clustering by the wander ignored: small at 9 %),
    and the study's fit returns the shape from that share; a Gaussian's share gives a shape near 0 (the share
    moves with α³ there)."""
    noise = StreamNoise(np.eye(1), (0.09,), np.random.default_rng(8), (ALPHA,))
    noise.start(2000)
    v = np.concatenate([noise.step(2000)[:, 0] for _ in range(100)])
    p = share_above(ALPHA, 0.09, 2.0)
    assert abs(v.var() - 1.0) < 0.02 and abs(np.mean(v > 2.0) - p) < 4 * math.sqrt(p * (1 - p) / v.size)
    assert tail_shape(p, 0.09) == pytest.approx(ALPHA, abs=1e-3)
    assert abs(tail_shape(share_above(0.0, 0.0, 2.0), 0.0)) < 1e-3
    assert math.isnan(tail_shape(0.2, 0.0))


def _skew_normal(alpha: float) -> Callable[[np.random.Generator, int], np.ndarray]:
    """Unit-variance skew-normal values of shape ``alpha`` drawn by scipy (not the calibration's generator)."""
    centre, var = (float(m) for m in skewnorm.stats(alpha, moments="mv"))
    return lambda rng, n: (skewnorm.rvs(alpha, size=(n, 1), random_state=rng) - centre) / math.sqrt(var)


@pytest.mark.slow
def test_a_skewed_law_is_calibrated_for_and_delivered() -> None:
    """Both sides, on kl_raw's warm-up law with its upper tail as measured (shape −1.74, no wander): the threshold
    calibrated for the skew delivers 10³ within 3 standard errors (the calibration's h_se through the slope
    of log ARL0 in h, and 1/√alarms); the Gaussian law's, on the same skewed values, delivers more than 2×
    (measured 3.6×: a quiet detector)."""
    skewed = dataclasses.replace(WARM_UP, skew=(ALPHA,))
    target = 1000.0
    found, gaussian = threshold(skewed, ((1.0,),), target, BUDGET), threshold(WARM_UP, ((1.0,),), target, BUDGET)
    assert found.threshold < gaussian.threshold - 3 * math.hypot(found.h_se, gaussian.h_se)
    values = _skew_normal(ALPHA)
    delivered, alarms = delivered_in_learned_units(skewed, found.threshold, 256, 6000, 84, values)
    tolerance = delivered_tolerance(skewed, ((1.0,),), target, alarms, BUDGET)
    assert abs(math.log(delivered / target)) <= tolerance, (found, delivered, alarms)
    assert delivered_in_learned_units(skewed, gaussian.threshold, 256, 6000, 85, values)[0] > 2.0 * target


def test_a_skew_is_for_a_spread_law_only_and_no_skew_keeps_the_key() -> None:
    """A shape without a law in learned units is refused; shape 0 is the Gaussian law, whose table key (and
    so its tabulated thresholds) is that of before the skew existed."""
    with pytest.raises(ValueError, match="skew"):
        dataclasses.replace(WARM_UP, spread_mean=(), spread_sd=(), skew=(ALPHA,))
    assert dataclasses.replace(WARM_UP, skew=(0.0,)).skew == ()
    assert "skew" not in key(WARM_UP) and "skew" in key(dataclasses.replace(WARM_UP, skew=(ALPHA,)))
    with pytest.raises(ValueError, match="scalar"):
        StreamNoise(np.eye(2), (), np.random.default_rng(1), (ALPHA,))


def test_the_laws_skew_reaches_the_warm_up_calibration_and_survives_a_restart() -> None:
    """``decision.warm_up_law``'s sixth number reaches the scalar warm-up calibration only; a shape beyond ±10 is
    refused with the key named; a calibration job carries it through its state, and a state saved before the
    skew existed loads as Gaussian."""
    from edge_monitor.config import ConfigError, config_from_mapping

    decision = config_from_mapping({"decision": {"warm_up_law": {
        "kl_raw": [-0.141, 0.071, 0.975, 0.105, 0.09, ALPHA]}}}).decision
    kl_raw = decision.detector_config("kl_raw")
    assert kl_raw.calibration("warm-up")["skew"] == (ALPHA,) and kl_raw.calibration("steady")["skew"] == ()
    assert decision.detector_config("joint").calibration("warm-up")["skew"] == ()
    with pytest.raises(ConfigError, match="decision.warm_up_law.kl_raw"):
        config_from_mapping({"decision": {"warm_up_law": {"kl_raw": [0.0, 0.1, 1.0, 0.1, 0.0, 11.0]}}})
    job = CalibrationJob(((0.0,), (1.0,)), "gauss", 100, 1000.0, 0.6, 1.0, "recursive", CalibrationBudget(),
                         "increase", 0.75, 3.0, **kl_raw.calibration("warm-up"))
    state = json.loads(json.dumps(job.to_dict()))
    assert CalibrationJob.from_dict(state) == job
    del state["skew"]
    assert CalibrationJob.from_dict(state).skew == ()


def test_a_detector_saved_before_the_skew_re_derives_its_threshold_for_it() -> None:
    """A warm-up detector learned under the Gaussian law and restored under the skewed one keeps its nominal and
    re-derives its threshold for the skew, a lower one (a lighter upper tail alarms less at the same h)."""
    from edge_monitor.stats.detector_config import DetectorConfig
    from edge_monitor.stats.sequential_detector import SequentialDetector

    before = DetectorConfig(arl0=200.0, direction="increase", allowance=0.75, calibrate_at="healthy_drift",
                            drift_mean=(-0.141,), drift_sd=(0.071,), spread_mean=(0.975,), spread_sd=(0.105,),
                            calibration_draws=16, calibration_steps=600)
    det, _ = learned_detector(before, seed=3)
    skewed = DetectorConfig(**{**before.__dict__, "warm_up_skew": (ALPHA,)})
    restored = SequentialDetector.from_state(skewed, json.loads(json.dumps(det.state_dict())))
    restored.update(0.0, 60)
    assert restored.state == "monitoring" and restored.calibrated_job is not None
    assert restored.calibrated_job.skew == (ALPHA,)
    assert restored.threshold is not None and det.threshold is not None and restored.threshold < det.threshold


def test_kl_raws_tail_shape_is_an_option_with_a_tabulated_threshold() -> None:
    """The shipped law is Gaussian (shape 0); kl_raw's fitted shape −1.76, set in ``[decision.warm_up_law]``, finds
    its thresholds in the shipped table (no simulation on the robot), lower than the Gaussian law's."""
    from edge_monitor.config import config_from_mapping
    from edge_monitor.pipeline.decision_config import DecisionConfig
    from edge_monitor.stats.threshold_table import lookup

    assert DecisionConfig().detector_config("kl_raw").calibration("warm-up")["skew"] == ()
    option = config_from_mapping({"decision": {"warm_up_law": {
        "kl_raw": [-0.141, 0.071, 0.975, 0.105, 0.09, -1.76]}}}).decision.detector_config("kl_raw")
    law = option.calibration("warm-up")
    settings = GaussianSettings(60, option.window, option.gamma0, option.rho, option.direction, option.allowance,
                                option.clip_sigma, law["at"], law["drift_mean"], law["drift_sd"], law["wander"],
                                law["transform"], law["spread_mean"], law["spread_sd"], law["skew"])
    gaussian = dataclasses.replace(settings, skew=())
    for target in (1e4, 2_629_800.0):
        found, plain = lookup(settings, target), lookup(gaussian, target)
        assert found is not None and plain is not None and found.threshold < plain.threshold - 0.5
