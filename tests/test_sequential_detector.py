"""Per-quantity sequential detector: learning → monitoring, alarms, bad data, persistence."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from edge_monitor.stats.calibration import DEFAULT_ARL0
from edge_monitor.stats.sequential_detector import DetectorConfig, DetectorConfigError, SequentialDetector

RECORD_FIELDS = {"state", "statistic", "threshold", "alarm", "change_cycle", "delta", "miss_probability", "reason",
                 "calibration"}


def test_learning_then_monitoring_with_the_decision_record_fields() -> None:
    rng = np.random.default_rng(0)
    det = SequentialDetector(DetectorConfig(n_nominal=20, window=30))
    first = det.update(0.1, cycle=100)
    assert first.state == "learning" and first.reason == "learning 1/20"
    assert set(first.to_dict()) == RECORD_FIELDS
    decisions = [det.update(v, cycle=101 + i) for i, v in enumerate(rng.normal(size=40))]
    assert decisions[17].state == "learning"
    assert decisions[18].state == "monitoring" and "learned" in decisions[18].reason
    record = decisions[-1].to_dict()
    assert set(record) == RECORD_FIELDS and record["state"] == "monitoring"
    assert record["threshold"] == pytest.approx(det.calibration.threshold)
    assert record["calibration"] == {"arl0": DEFAULT_ARL0, "at": "boundary", "stage": "warm-up",
                                     "method": det.calibration.method, "h_se": det.calibration.h_se}
    assert json.loads(json.dumps(record)) == record
    assert record["change_cycle"] >= 119


def test_alarm_on_a_three_sigma_change_is_latched_until_reset() -> None:
    rng = np.random.default_rng(1)
    det = SequentialDetector(DetectorConfig(n_nominal=60, window=100))
    values = np.r_[rng.normal(size=60 + 100), rng.normal(size=40) + 3.0]
    decisions = [det.update(v, cycle=1000 + i) for i, v in enumerate(values)]
    change_cycle = 1000 + 160
    assert not any(d.alarm for d in decisions[:160])
    first = next(i for i, d in enumerate(decisions) if d.alarm)
    assert 160 <= first <= 175                     # a 3σ change: a handful of cycles (see DETECTION.md)
    assert abs(decisions[first].change_cycle - change_cycle) <= 3
    assert decisions[first].delta[0] == pytest.approx(3.0, abs=1.5)
    back_to_normal = det.update(0.0, cycle=2000)
    assert back_to_normal.alarm, "alarm must stay latched"
    det.reset()
    after = det.update(0.0, cycle=2001)
    assert after.state == "learning" and not after.alarm and det.counters()["resets"] == 1


@pytest.mark.slow
def test_calibrated_threshold_gives_the_stated_false_alarm_rate_and_still_detects() -> None:
    """Both sides, Gaussian nominal data, the product's learning (60 values) and window (100), calibrated
    at the nominal (the warm-up default, at the allowance boundary, is by design quieter on nominal data).

    Quiet side: 60 detectors, each learning a fresh nominal and calibrating for ARL0 = 100 cycles, then
    watching 1,000 cycles of nominal data; after an alarm the detector starts again from its learned
    state, as after an acknowledgement. The stated ARL0 is the fleet's (cycles per false alarm over all
    detectors): exposure / alarms. The per-nominal rate has a coefficient of variation of about 1 … 1.5
    across learned nominals (docs/DETECTION.md), so the fleet rate of 60 has a standard error of at most
    0.2 of itself: the acceptance band 0.5 … 2 × ARL0 is ≥ 2.5 standard errors from the target.
    (The mean of first run lengths is not this rate: by Jensen it exceeds it when nominals differ.)
    Alarm side: a 2σ shift after the learning raises the alarm in ≥ 54 of the 60 runs within 100 cycles.
    """
    rng = np.random.default_rng(2)
    arl0, watch = 100.0, 1000
    config = DetectorConfig(arl0=arl0, calibration_draws=32, calibration_steps=1200, calibrate_at="nominal")
    exposure, alarms, detected = 0, 0, 0
    for _ in range(60):
        learner = SequentialDetector(config)
        for i, v in enumerate(rng.normal(size=60)):
            learner.update(v, i)
        learned = json.loads(json.dumps(learner.state_dict()))
        quiet = SequentialDetector.from_state(config, learned)
        for t in range(1, watch + 1):
            if quiet.update(rng.normal(), 60 + t).alarm:
                alarms += 1
                quiet = SequentialDetector.from_state(config, learned)
        exposure += watch
        shifted = SequentialDetector.from_state(config, learned)                 # same learning, same threshold
        detected += any(shifted.update(rng.normal() + 2.0, 60 + t).alarm for t in range(1, 101))
    measured = exposure / max(alarms, 1)
    print(f"measured ARL0 {measured:.0f} for {arl0:.0f} ({alarms} alarms); detected {detected}/60")
    assert 0.5 * arl0 <= measured <= 2.0 * arl0, measured
    assert detected >= 54, detected


def test_non_finite_values_are_skipped_counted_and_do_not_touch_state() -> None:
    rng = np.random.default_rng(3)
    det = SequentialDetector(DetectorConfig(n_nominal=15, window=10, density="kde"))
    for i, v in enumerate(rng.normal(size=25)):
        det.update(v, i)
    before = json.dumps(det.state_dict(), sort_keys=True)
    for bad in (math.nan, math.inf, -math.inf):
        d = det.update(bad, 99)
        assert d.reason == "non-finite value skipped" and d.state == "monitoring"
    d = det.update([1.0, 2.0], 100)
    assert "expected 1 number" in d.reason
    d = det.update("abc", 101)  # type: ignore[arg-type]
    assert "expected 1 number" in d.reason
    after = det.state_dict()
    assert after["counters"] == {"skipped_nonfinite": 3, "skipped_bad_shape": 2, "resets": 0, "fits": 1}
    after["counters"] = json.loads(before)["counters"]
    assert json.dumps(after, sort_keys=True) == before


def test_constant_nominal_data_keep_the_detector_learning_with_a_reason() -> None:
    det = SequentialDetector(DetectorConfig(n_nominal=12, window=10))
    for i in range(30):
        d = det.update(0.25, i)
    assert d.state == "learning" and "constant" in d.reason
    rng = np.random.default_rng(4)
    for i, v in enumerate(0.25 + 0.01 * rng.normal(size=12)):
        d = det.update(v, 30 + i)
    assert d.state == "monitoring"


def test_vector_detector_and_state_round_trip_continue_identically() -> None:
    rng = np.random.default_rng(5)
    det = SequentialDetector(DetectorConfig(dim=3, n_nominal=40, window=25, density="gce", mode="exact", pf=1e-3))
    for i, v in enumerate(rng.normal(size=(70, 3))):
        det.update(v, i)
    back = SequentialDetector.from_state(det.config, json.loads(json.dumps(det.state_dict())))
    for i, v in enumerate(rng.normal(size=(30, 3)) + [0.0, 1.0, 0.0]):
        a, b = det.update(v, 70 + i), back.update(v, 70 + i)
        assert a.to_dict() == b.to_dict()
        assert len(a.delta) == 3


def test_state_round_trip_during_learning() -> None:
    det = SequentialDetector(DetectorConfig(n_nominal=10, window=5, density="gauss"))
    for i in range(6):
        det.update(float(i), i)
    back = SequentialDetector.from_state(det.config, json.loads(json.dumps(det.state_dict())))
    assert back.update(7.0, 7).reason == det.update(7.0, 7).reason == "learning 7/10"


@pytest.mark.parametrize("kwargs, match", [
    ({"n_nominal": 3, "density": "kde"}, "needs 5"),
    ({"density": "parzen"}, "choose one of"),
    ({"pf": 0.0}, "between 0 and 1"),
    ({"window": 0}, "window"),
    ({"gamma0": 1.5}, "gamma0"),
    ({"mode": "fast"}, "mode"),
    ({"dim": 0}, "dim"),
])
def test_bad_configuration_is_a_clear_error(kwargs: dict, match: str) -> None:
    with pytest.raises(DetectorConfigError, match=match):
        SequentialDetector(DetectorConfig(**kwargs))


def test_default_false_alarm_setting_is_the_documented_product_default() -> None:
    config = SequentialDetector(DetectorConfig()).config
    assert config.arl0 == DEFAULT_ARL0 == 10_000 and config.pf is None


def test_threshold_when_the_smallest_threshold_already_reaches_the_target() -> None:
    """Statistics that stay 0 until one late excursion (an allowance calibrated inside its null): the
    first grid threshold already gives ARL0 ≥ target. Found by the ARL study: the interpolation read
    one point past the reliable range and raised."""
    from edge_monitor.stats.calibration import H_STEP, _threshold_for

    statistics = np.zeros((16, 600))
    statistics[:, 590] = 1.2 * H_STEP            # one excursion per detector, just above the first grid point
    h, method, events, _ = _threshold_for(statistics, arl0=100.0)
    assert h == H_STEP and method == "simulated" and events == 16
    statistics[:8, 590] = 0.0                     # not reliable beyond: half the detectors never alarm
    statistics[:8, 300] = 3 * H_STEP
    h, method, _, _ = _threshold_for(statistics, arl0=400.0)
    assert H_STEP <= h <= 3 * H_STEP and method in ("simulated", "extrapolated")


def test_a_failed_inline_calibration_falls_back_to_the_asymptotic_threshold(monkeypatch, caplog) -> None:
    """Replay calibrates inline: a calibration that fails (too few simulated alarms) must not raise out
    of update(); the detector monitors with the asymptotic Pf = 1e-9 threshold and says so."""
    from edge_monitor.stats.calibration import CalibrationError, CalibrationJob
    from edge_monitor.stats.glr import threshold_from_pf

    def fail(self):
        raise CalibrationError("too few simulated alarms to calibrate")

    monkeypatch.setattr(CalibrationJob, "run", fail)
    det = SequentialDetector(DetectorConfig(n_nominal=20, window=30))
    with caplog.at_level("WARNING"):
        decisions = [det.update(v, cycle=i) for i, v in enumerate(np.random.default_rng(1).normal(size=25))]
    assert decisions[-1].state == "monitoring"
    assert det.calibration.method == "fallback" and det.threshold == pytest.approx(threshold_from_pf(1e-9, 1))
    assert any("threshold calibration failed" in r.getMessage() for r in caplog.records)


def test_new_calibration_settings_rederive_a_restored_threshold_on_the_same_nominal() -> None:
    """Where the calibration simulates is not learned: a detector restored under another calibration point
    and drift keeps its nominal and statistic and re-derives its threshold (here the measured warm-up drift
    instead of the allowance boundary: a lower threshold); restored under its own settings it keeps its
    threshold; a learned setting changed is still a mismatch (the detector relearns)."""
    import dataclasses

    from edge_monitor.errors import StateMismatch

    rng = np.random.default_rng(11)
    config = DetectorConfig(n_nominal=60, window=100, direction="increase", allowance=0.75, clip_sigma=3.0,
                            arl0=1000.0)
    det = SequentialDetector(config)
    for i, v in enumerate(rng.normal(size=80)):
        det.update(v, i)
    assert det.calibration is not None and det.calibration.at == "boundary"
    saved = json.loads(json.dumps(det.state_dict()))
    drifting = dataclasses.replace(config, calibrate_at="healthy_drift", drift_mean=(0.05,), drift_sd=(0.41,))
    same, back = SequentialDetector.from_state(config, saved), SequentialDetector.from_state(drifting, saved)
    v = float(rng.normal())
    a, b = same.update(v, 80), back.update(v, 80)
    assert a.state == b.state == "monitoring" and a.statistic == pytest.approx(b.statistic)   # not relearned
    assert same.threshold == det.threshold
    assert back.calibration is not None and back.calibration.at == "healthy_drift"
    assert back.threshold is not None and det.threshold is not None and back.threshold < det.threshold
    again = SequentialDetector.from_state(config, json.loads(json.dumps(back.state_dict())))
    again.update(v, 81)
    assert again.threshold == pytest.approx(det.threshold)               # back to the boundary's
    with pytest.raises(StateMismatch, match="allowance"):
        SequentialDetector.from_state(dataclasses.replace(config, allowance=0.5), saved)


def _old_fingerprint(config: DetectorConfig) -> dict:
    """A detector fingerprint as the versions before 2026-11-28 saved it (their rule, verbatim): the
    calibration point and drifts in it unless at the boundary default, the steady settings unless all five
    (the calibration point among them) were the defaults."""
    from dataclasses import asdict

    from edge_monitor.stats.detector_config import STEADY_DEFAULTS

    out = {**asdict(config), "drift_mean": list(config.drift_mean), "drift_sd": list(config.drift_sd),
           "steady_drift_mean": list(config.steady_drift_mean), "steady_drift_sd": list(config.steady_drift_sd),
           "steady_wander": list(config.steady_wander), "transform_axes": list(config.transform_axes)}
    del out["arl0"]
    if config.calibrate_at == "boundary" and not (config.drift_mean or config.drift_sd):
        for key in ("calibrate_at", "drift_mean", "drift_sd"):
            del out[key]
    steady = ("steady_at", "steady_nominal", "steady_density", "steady_transform", "steady_simulate_from")
    if tuple(out[key] for key in steady) == STEADY_DEFAULTS:
        for key in (*steady, "transform_axes"):
            del out[key]
    return json.loads(json.dumps(out))


@pytest.mark.parametrize("changes", [{}, {"steady_at": "boundary"}, {"steady_at": "nominal"},
                                     {"calibrate_at": "healthy_drift", "drift_mean": (0.1,), "drift_sd": (0.2,)},
                                     {"steady_drift_mean": (0.04,), "steady_drift_sd": (0.03,),
                                      "steady_wander": (0.09,), "transform_axes": (True,)}])
def test_a_state_saved_by_an_older_version_matches_whatever_its_calibration_settings(changes: dict) -> None:
    """An older version's fingerprint (with calibration settings in it, and with the steady group kept
    where the calibration point alone differed from the default) matches the same config now: the
    detector is restored, not relearned; a learned setting changed still does not match."""
    import dataclasses

    from edge_monitor.errors import StateMismatch
    from edge_monitor.stats.detector_config import learned_part

    config = dataclasses.replace(DetectorConfig(n_nominal=20, window=30, direction="increase", allowance=0.75,
                                                arl0=200.0), **changes)
    assert learned_part(_old_fingerprint(config)) == config.fingerprint()
    det = SequentialDetector(config)
    for i, v in enumerate(np.random.default_rng(2).normal(size=25)):
        det.update(v, i)
    state = {**json.loads(json.dumps(det.state_dict())), "config": _old_fingerprint(config)}
    assert SequentialDetector.from_state(config, state).state == "monitoring"
    with pytest.raises(StateMismatch):
        SequentialDetector.from_state(dataclasses.replace(config, window=31), state)


def test_a_rederived_threshold_does_not_inherit_the_first_calibrations_waiting_maximum() -> None:
    """The largest statistic seen while the first threshold was computed (kept in the state) decides only
    that first threshold: a threshold re-derived on restore (here lower) must not latch an alarm from it,
    while a first calibration still under way at the save does."""
    import dataclasses

    config = DetectorConfig(n_nominal=60, window=100, direction="increase", allowance=0.75, clip_sigma=3.0,
                            arl0=1000.0)
    det = SequentialDetector(config)
    rng = np.random.default_rng(4)
    for i, v in enumerate(rng.normal(size=70)):
        det.update(v, i)
    assert det.threshold is not None
    crossing = {"statistic": 0.9 * det.threshold, "cycle": 66, "change_cycle": 62}
    saved = {**json.loads(json.dumps(det.state_dict())), "waiting": crossing}
    drifting = dataclasses.replace(config, calibrate_at="healthy_drift", drift_mean=(0.05,), drift_sd=(0.41,))
    back = SequentialDetector.from_state(drifting, saved)
    back.update(0.0, 70)
    assert back.threshold is not None and back.threshold < 0.9 * det.threshold and not back.alarmed
    first = {**saved, "calibration": None, "calibrated_job": None, "calibration_job": saved["calibrated_job"],
             "glr": {**saved["glr"], "threshold": math.inf}}       # saved before its first threshold arrived
    pending = SequentialDetector.from_state(drifting, first)
    pending.update(0.0, 70)
    assert pending.threshold == pytest.approx(back.threshold) and pending.alarmed
    # the alarm is the crossing's: its statistic, cycle and change cycle, not those of the cycle it came in
    assert pending.crossing == crossing
    older = {**first, "waiting_max": crossing["statistic"]}            # a state saved before "waiting"
    del older["waiting"]
    restored = SequentialDetector.from_state(drifting, older)
    restored.update(0.0, 70)
    assert restored.alarmed and restored.crossing["statistic"] == crossing["statistic"]
