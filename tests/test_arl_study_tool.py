"""tools/studies/arl_study.py's measurement of run lengths on real series (the renewal the agent study uses)."""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).resolve().parent.parent / "tools" / "studies"))

from arl_study import real_run_lengths  # noqa: E402

from edge_monitor.stats.sequential_detector import DetectorConfig  # noqa: E402


def test_run_lengths_renew_after_each_crossing_and_count_only_monitored_cycles() -> None:
    """400 values, a +6σ step at 100: the first detector (learned on 0–59) crosses a moderate
    threshold once, soon after the step; the relearned one (on shifted values only) never does. So
    cycles / crossings = 400 − 2 × 60 learning cycles = 280, whatever the crossing cycle; a threshold
    no statistic reaches leaves the run length infinite (no crossing)."""
    rng = np.random.default_rng(4)
    x = rng.normal(size=(400, 1))
    x[100:] += 6.0
    config = DetectorConfig(density="gauss", n_nominal=60, window=50, direction="increase", allowance=0.0)
    run_lengths = real_run_lengths([x], config, np.array([5.0, 1e6]))
    assert run_lengths[0] == 280.0
    assert np.isinf(run_lengths[1])


def test_agent_arl_runs_the_agents_detectors_with_the_chosen_calibration() -> None:
    """``agent_arl`` feeds per-cycle detector inputs to the agent's DetectorBank: 90 healthy cycles of
    one joint leave at most 90 − 60 learning = 30 monitored cycles per quantity (cycles whose value the
    statistic tested), a detector that alarms starts a new run, and each row names the calibration
    used."""
    from arl_study import agent_arl

    rng = np.random.default_rng(3)
    rows = [{"wear_score": float(w), "kl_raw": float(a), "kl_weighted": float(b)}
            for w, a, b in zip(rng.normal(size=90), rng.lognormal(-3, 0.3, 90), rng.lognormal(-4, 0.3, 90))]
    out = agent_arl([{0: rows}], 50.0, draws=16, calibrate_at="healthy_drift")
    assert {r["quantity"] for r in out} == {"wear", "kl_raw", "kl_weighted", "joint"}
    for r in out:
        assert r["calibrate_at"] == "healthy_drift" and r["runs"] >= 1
        assert r["runs"] == 1 + r["false_alarms"] and 0 < r["monitored_cycles"] <= 30
    assert all(r["calibrate_at"] == "boundary" for r in agent_arl([{0: rows}], 50.0, draws=16, boundary=True))


def test_agent_arl_reports_the_steady_stage_once_the_motor_temperature_settles() -> None:
    """With a flat motor temperature the joint settles once the test's 240-cycle window is full; every
    detector then learns its steady nominal (240 cycles), calibrated for the healthy drift after learning,
    and the rows split into the two stages. A
    steady-stage alarm is acknowledged (the statistic restarts on the same nominal), so there every
    run but the first starts with a false alarm."""
    from arl_study import agent_arl

    rng = np.random.default_rng(5)
    n = 700
    rows = [{"wear_score": float(w), "kl_raw": float(a), "kl_weighted": float(b), "motor_temperature": float(t)}
            for w, a, b, t in zip(rng.normal(size=n), rng.lognormal(-3, 0.3, n), rng.lognormal(-4, 0.3, n),
                                  rng.normal(45.0, 3.0, n))]
    out = agent_arl([{0: rows}], 200.0, draws=16)
    steady = [r for r in out if r["stage"] == "steady"]
    assert {r["quantity"] for r in steady} == {"wear", "kl_raw", "kl_weighted", "joint"}
    for r in steady:
        assert r["calibrate_at"] == "healthy_drift" and r["runs"] == 1 + r["false_alarms"]
        assert 0 < r["monitored_cycles"] <= n - 239 - 240
    warm = {r["quantity"]: r for r in out if r["stage"] == "warm-up"}
    assert all(warm[q]["monitored_cycles"] > 0 for q in warm)


def test_agent_arl_acknowledges_warm_up_alarms_by_default_and_resets_them_when_asked() -> None:
    """``warm_up_alarm="acknowledge"`` (the default, as the agent handles an alarm judged false): a warm-up false
    alarm restarts the statistic on the same nominal, so every
    run after the first starts with an alarm and no cycle is spent relearning; with "reset" each alarm is followed
    by a new learning phase of 60 cycles. A stream that sits 3 σ above what it learned (after 60 cycles of N(0, 1))
    alarms in both, and the acknowledging detector tests more cycles; anything else is refused."""
    from arl_study import agent_arl

    rng = np.random.default_rng(4)
    n = 400
    shift = np.where(np.arange(n) < 60, 0.0, 3.0)
    rows = [{"wear_score": float(w + s), "kl_raw": float(a), "kl_weighted": float(b)}
            for w, s, a, b in zip(rng.normal(size=n), shift, rng.lognormal(-3, 0.3, n), rng.lognormal(-4, 0.3, n))]
    reset = {r["quantity"]: r for r in agent_arl([{0: rows}], 50.0, draws=16, warm_up_alarm="reset")
             if r["stage"] == "warm-up"}
    ack = {r["quantity"]: r for r in agent_arl([{0: rows}], 50.0, draws=16) if r["stage"] == "warm-up"}
    assert reset["wear"]["false_alarms"] >= 1 and ack["wear"]["false_alarms"] >= 1
    assert ack["wear"]["runs"] == 1 + ack["wear"]["false_alarms"]
    assert ack["wear"]["monitored_cycles"] > reset["wear"]["monitored_cycles"]
    with pytest.raises(ValueError, match="warm_up_alarm"):
        agent_arl([{0: rows}], 50.0, draws=16, warm_up_alarm="ignore")


def test_each_row_carries_the_band_a_calibrated_detector_would_show() -> None:
    """With 15.1 alarms due (the quick run's rows at target 200) a calibrated detector with Poisson alarms lands
    between λ/23 and λ/8 (the count's 2.5 % and 97.5 % points, 8 and 23): wider than 0.67–1.5; with 1 197 due
    (the held-out run's warm-up rows at 50) within ±6 %; no upper end where no alarm is a likely count."""
    from arl_study import calibrated_ratio_band

    low, high = calibrated_ratio_band(15.1)
    assert low == pytest.approx(15.1 / 23) and high == pytest.approx(15.1 / 8)
    assert low < 0.67 and high > 1.5
    low, high = calibrated_ratio_band(1197.0)
    assert 0.94 < low < 1.0 < high < 1.06
    assert calibrated_ratio_band(1.0)[1] is None and calibrated_ratio_band(0.0) == [None, None]
