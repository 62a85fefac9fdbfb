"""The steady stage's Yeo–Johnson transform: the map itself (against scipy, monotone, invertible), its
fit, its persistence, and a detector that watches transformed values (docs/DETECTION.md, "Two stages")."""

from __future__ import annotations

import json
from dataclasses import replace

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy import stats

from edge_monitor.pipeline.detectors import DecisionConfig
from edge_monitor.stats.detector_config import DetectorConfigError
from edge_monitor.stats.normalising_transform import LAMBDA_MAX, LAMBDA_MIN, TransformError, YeoJohnson, yeo_johnson
from edge_monitor.stats.sequential_detector import DetectorConfig, SequentialDetector

finite = st.floats(-50.0, 50.0, allow_nan=False)
lambdas = st.floats(LAMBDA_MIN, LAMBDA_MAX)


@settings(max_examples=60, deadline=None)
@given(st.lists(finite, min_size=1, max_size=30), lambdas)
def test_the_map_is_scipys_yeo_johnson(values: list[float], lam: float) -> None:
    u = np.asarray(values)
    assert np.allclose(yeo_johnson(u, lam), stats.yeojohnson(u, lam), rtol=1e-9, atol=1e-12)


@settings(max_examples=60, deadline=None)
@given(st.lists(st.tuples(finite, lambdas), min_size=1, max_size=30))
def test_one_exponent_per_value_maps_each_value_as_scipy_does(pairs: list[tuple[float, float]]) -> None:
    u, lam = (np.asarray(column) for column in zip(*pairs))
    expected = [stats.yeojohnson(np.array([x]), float(k))[0] for x, k in zip(u, lam)]
    assert np.allclose(yeo_johnson(u, lam), expected, rtol=1e-9, atol=1e-12)


@settings(max_examples=60, deadline=None)
@given(st.lists(finite, min_size=2, max_size=30, unique=True), lambdas, st.floats(-5, 5), st.floats(0.1, 10))
def test_the_transform_is_increasing_and_inverts(values: list[float], lam: float, center: float,
                                                 scale: float) -> None:
    transform = YeoJohnson([center], [scale], [lam])
    y = np.sort(np.asarray(values))[:, None]
    z = transform.apply(y)
    step = np.diff(z[:, 0])
    assert np.all(step >= 0) and np.all(step[np.diff(y[:, 0]) > 1e-3] > 0)   # an increase stays one
    assert np.allclose(transform.invert(z), y, rtol=1e-7, atol=1e-7 * scale)


def test_the_fit_removes_the_skew_and_leaves_gaussian_values_alone() -> None:
    rng = np.random.default_rng(1)
    left = -rng.gamma(4.0, size=(240, 1))                      # skewness ≈ −1
    transform = YeoJohnson.fit(left)
    assert transform.lambdas[0] > 1.2                            # bends the long left tail in
    assert abs(stats.skew(transform.apply(left)[:, 0])) < 0.15 < abs(stats.skew(left[:, 0]))
    gaussian = YeoJohnson.fit(rng.normal(3.0, 2.0, size=(240, 2)))
    assert np.all(np.abs(gaussian.lambdas - 1.0) < 0.4)          # ≈ 3 standard errors of λ̂ at N0 = 240
    assert np.allclose(gaussian.center, 3.0, atol=0.4) and np.allclose(gaussian.scale, 2.0, rtol=0.15)


@pytest.mark.parametrize("values", [np.zeros((20, 1)), np.ones((2, 1)), np.full((10, 1), np.nan)])
def test_unusable_learning_values_are_a_clear_error(values: np.ndarray) -> None:
    with pytest.raises(TransformError, match="Yeo-Johnson"):
        YeoJohnson.fit(values)


@pytest.mark.parametrize("state", [{}, {"center": [0.0], "scale": [0.0], "lambdas": [1.0]},
                                   {"center": [0.0], "scale": [1.0], "lambdas": [9.0]},
                                   {"center": "x", "scale": [1.0], "lambdas": [1.0]},
                                   {"center": [0.0, 1.0], "scale": [1.0], "lambdas": [1.0]}])
def test_a_damaged_saved_transform_is_rejected(state: dict) -> None:
    with pytest.raises(TransformError, match="Yeo-Johnson"):
        YeoJohnson.from_state(state)


def _steady_detector(transform: str = "yeo-johnson", seed: int = 3) -> tuple[SequentialDetector, np.random.Generator]:
    """A detector in its steady stage on left-skewed values (−Gamma(4)), the warm-up on N(0, 1); its
    threshold simulated from its Gaussian model, not from its values, so that the transform alone makes
    the model fit (tests/test_calibration_from_values.py has the other remedy)."""
    config = DetectorConfig(n_nominal=20, steady_nominal=240, density="gauss", calibration_draws=16,
                            calibration_steps=600, direction="increase", allowance=0.75, arl0=50,
                            steady_transform=transform, steady_simulate_from="model")
    rng = np.random.default_rng(seed)
    det = SequentialDetector(config)
    for i, v in enumerate(rng.normal(size=20)):
        det.update(v, i)
    det.begin_steady()
    for i, v in enumerate(-rng.gamma(4.0, size=240)):
        det.update(v, 20 + i)
    assert det.stage == "steady" and det.threshold is not None
    return det, rng


def test_a_steady_detector_watches_transformed_values_and_reports_shifts_in_its_units() -> None:
    det, rng = _steady_detector()
    assert det.transform is not None and det.transform.lambdas[0] > 1.0
    for i, v in enumerate(-rng.gamma(4.0, size=30) + 6.0):       # +6 units ≈ 3 σ: an alarm
        decision = det.update(v, 260 + i)
    assert decision.alarm and decision.delta is not None
    assert 3.0 < decision.delta[0] < 9.0                         # in the units fed, not transformed ones
    plain, _ = _steady_detector("none")
    assert plain.transform is None


def test_a_transformed_detector_continues_identically_after_a_restore_and_rejects_a_damaged_one() -> None:
    det, rng = _steady_detector()
    state = json.loads(json.dumps(det.state_dict()))
    restored = SequentialDetector.from_state(det.config, state)
    for i, v in enumerate(-rng.gamma(4.0, size=50)):
        assert restored.update(v, 300 + i) == det.update(v, 300 + i)
    for damaged in ({**state["transform"], "lambdas": [1.0, 1.0]}, {"center": [0.0]}):
        with pytest.raises(ValueError, match="transform"):
            SequentialDetector.from_state(det.config, {**state, "transform": damaged})
    with pytest.raises(ValueError, match="transform"):                # a warm-up detector has none
        SequentialDetector.from_state(det.config, {**state, "stage": "warm-up"})


def _false_alarms(transform: str, seed: int, cycles: int) -> int:
    """False alarms of one steady detector (target ARL0 = 50) on ``cycles`` more values like its nominal,
    each alarm acknowledged (the statistic restarts)."""
    det, rng = _steady_detector(transform, seed)
    alarms = 0
    for i, v in enumerate(-rng.gamma(4.0, size=cycles)):
        if det.update(v, 260 + i).alarm:
            alarms += 1
            det.acknowledge()
    return alarms


def test_on_skewed_values_the_transform_makes_the_stated_run_length_true_and_without_it_it_is_not() -> None:
    """Both sides on left-skewed healthy values (skewness −1, like a warm joint's log kl.raw but
    stronger): 3 detectors × 2 000 cycles at ARL0 = 50 expect 120 false alarms. With the transform the
    measured ARL0 lies within the issue's band 0.5–2× (Poisson error alone ±10 %; the rest is each
    detector's learning error). Without it the Gaussian overstates the right tail: the threshold is too
    high and the detectors alarm several times less often than stated (seeds fixed; measured 0.9× and
    30× on 4 × 3 000 cycles)."""
    cycles, seeds, target = 2000, (0, 1, 2), 50
    with_transform = sum(_false_alarms("yeo-johnson", s, cycles) for s in seeds)
    without = sum(_false_alarms("none", s, cycles) for s in seeds)
    measured = len(seeds) * cycles / max(with_transform, 1)
    assert 0.5 * target <= measured <= 2.0 * target, (with_transform, measured)
    assert without * 4 < with_transform, (without, with_transform)


def test_only_the_selected_axes_are_bent_and_the_agent_selects_every_scalar_and_the_vectors_log_axes() -> None:
    rng = np.random.default_rng(4)
    values = np.column_stack([-rng.gamma(4.0, size=240), -rng.gamma(4.0, size=240)])
    transform = YeoJohnson.fit(values, (False, True))
    assert transform.lambdas[0] == 1.0 and transform.lambdas[1] > 1.2
    with pytest.raises(TransformError, match="axis flags"):
        YeoJohnson.fit(values, (True,))
    config = DecisionConfig()
    axes = {q: config.detector_config(q).transform_axes for q in config.quantities}
    assert axes == {"wear": (True,), "kl_raw": (True,), "kl_weighted": (True,), "joint": (False, True, True)}
    assert DecisionConfig(log_scale=False).detector_config("joint").transform_axes == (False, False, False)
    assert DecisionConfig(log_scale=False).detector_config("kl_raw").transform_axes == (True,)
    with pytest.raises(DetectorConfigError, match="transform_axes"):
        DetectorConfig(dim=2, transform_axes=(True,))


def test_a_steady_detector_with_no_axis_selected_has_no_transform() -> None:
    config = DecisionConfig(n_nominal=20, steady_nominal=40, density="gauss", calibration_draws=16,
                            calibration_steps=400, quantities=("wear",))
    det = SequentialDetector(replace(config.detector_config("wear"), transform_axes=(False,)))
    rng = np.random.default_rng(8)
    det.begin_steady()
    for i, v in enumerate(-rng.gamma(4.0, size=40)):
        det.update(v, i)
    assert det.stage == "steady" and det.threshold is not None and det.transform is None
    assert det.state_dict()["transform"] is None


def test_a_value_too_large_to_transform_is_skipped_and_counted_and_the_map_has_no_ceiling() -> None:
    det, rng = _steady_detector()
    decision = det.update(1e300, 300)                                   # z overflows to inf
    assert det.skipped_nonfinite == 1 and "too large" in decision.reason
    assert det.update(-4.0, 301).state == "monitoring"                 # and it goes on
    for lam in (LAMBDA_MIN, LAMBDA_MAX):                                # both branches unbounded
        z = YeoJohnson([0.0], [1.0], [lam]).apply(np.array([[-1e6], [1e6]]))
        assert z[0, 0] < -10 and z[1, 0] > 10


def test_a_saved_transform_the_settings_could_not_have_learned_is_rejected() -> None:
    det, _ = _steady_detector()
    state = json.loads(json.dumps(det.state_dict()))
    with pytest.raises(ValueError, match="transform"):                  # the transform is off
        SequentialDetector.from_state(replace(det.config, steady_transform="none"), state)
    one_axis = replace(det.config, transform_axes=(False,))
    with pytest.raises(ValueError, match="transform"):                  # λ ≠ 1 on an axis not selected
        SequentialDetector.from_state(one_axis, {**state, "config": one_axis.fingerprint()})
    with pytest.raises(TransformError):                                 # a scale no data could give
        YeoJohnson.from_state({"center": [0.0], "scale": [1e-300], "lambdas": [1.0]})
