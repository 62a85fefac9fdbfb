"""The always-watching study tools (tools/studies/watching_study.py, temperature_law_study.py) on synthetic
inputs: the temperature law they fit, and what their reports count."""

from __future__ import annotations

import math
import sys
from pathlib import Path

import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tools" / "studies"))

import ramp_trace  # noqa: E402
import temperature_law_study  # noqa: E402
import watching_study  # noqa: E402


def test_the_law_fit_recovers_a_known_drift():
    """A joint warming 35 → 60 °C whose log KL distances drift 0.3·√d σ (d above the span of its first 60
    cycles) and whose wear score does not: the fitted a is 0.3 within 4 of its standard errors (1/√Σd, Σd over
    ≈ 640 cycles ≈ 9 000 °C: 0.011), the wear score's 0 within the same."""
    rng = np.random.default_rng(2)
    n = 700
    motor = np.concatenate([np.full(60, 35.0), np.linspace(35.0, 60.0, n - 60)]) + 5.0
    top = 40.0
    rows = []
    for t in motor:
        d = max(0.0, t - top)
        shift = 0.3 * math.sqrt(d)
        rows.append({"motor_temperature": float(t), "wear_score": rng.normal(),
                     "kl_raw": math.exp(rng.normal(-3.0, 0.3) + 0.3 * shift),
                     "kl_weighted": math.exp(rng.normal(-4.0, 0.3) + 0.3 * shift)})
    law = temperature_law_study.law(rows, 60, n)
    assert law["kl_raw"] == pytest.approx(0.3, abs=0.05) and law["kl_weighted"] == pytest.approx(0.3, abs=0.05)
    assert abs(law["wear_score"]) < 0.05


@pytest.mark.parametrize("later_sd", [1.0, 0.5])
def test_what_the_slack_leaves_reports_the_values_spread(later_sd):
    """A joint warming 35 → 60 °C whose inputs keep their mean and have standard deviation ``later_sd`` after the
    60 cycles their nominals learn from: the spread the study reports is that sd in the nominal's units. Each
    estimate's relative error: the nominal's sd from 60 values ≈ 0.09, the spread's own from ≈ 500 values ≈ 0.03, so
    4 combined errors ≈ 0.38·later_sd; the two cases (1 and 0.5) lie further apart than that, both sides checked."""
    from edge_monitor.pipeline.decision_config import DecisionConfig

    rng = np.random.default_rng(3)
    n = 700
    motor = np.concatenate([np.full(60, 35.0), np.linspace(35.0, 60.0, n - 60)]) + 5.0
    rows = []
    for k, t in enumerate(motor):
        sd = 1.0 if k < 60 else later_sd
        rows.append({"motor_temperature": float(t), "wear_score": rng.normal(0.0, sd),
                     "kl_raw": math.exp(rng.normal(-3.0, 0.3 * sd)), "kl_weighted": math.exp(rng.normal(-4.0, 0.3 * sd))})
    left = temperature_law_study.left_by_slack(rows, DecisionConfig(arl0_cycles=1e7), n)
    for quantity in ("wear", "kl_raw", "kl_weighted"):
        mean, spread = left[quantity]
        assert spread == pytest.approx(later_sd, abs=0.38 * later_sd), quantity
        assert math.isfinite(mean)


def test_the_report_counts_coverage_alarms_and_false_alarms():
    coverage = {"wear": {"share": 1.0, "recent": 1.0, "cycles": 900, "not_tested": {}},
                "kl_raw": {"share": 0.95, "recent": 1.0, "cycles": 900, "not_tested": {"held": 45}},
                "kl_weighted": {"share": 0.5, "recent": 0.5, "cycles": 900, "not_tested": {"held_warm": 450}},
                "joint": {"share": 0.95, "recent": 1.0, "cycles": 900, "not_tested": {"held": 45}}}
    run = {"seed": 9, "worn": [1], "coverage": {"0": coverage, "1": coverage},
           "monitored": {"0": {"wear": 900, "kl_raw": 855}, "1": {"wear": 900}},
           "monitored_steady": {"0": {"wear": 300, "kl_raw": 300}},
           "alarms": [{"joint": 0, "cycle": 500, "quantity": "kl_raw", "stage": "warm-up", "wear": 0.0},
                      {"joint": 1, "cycle": 700, "quantity": "wear", "stage": "warm-up", "wear": 21.5}]}
    text = watching_study.report([run], arl0=1000.0)
    assert "best distribution detector 95.0 %" in text and "wear score 100.0 %" in text
    assert "seed 9 joint 1 (worn): first alarm cycle 700, wear (warm-up), true wear 21.5" in text
    counts = watching_study.false_alarms([run], 1000.0)
    assert counts["warm-up"] == {"alarms": 1, "cycles": 1155, "due": pytest.approx(1.155)}
    assert counts["steady"] == {"alarms": 0, "cycles": 600, "due": pytest.approx(0.6)}
    # An alarm whose decision states no stage (the joint vector's) belongs to its detector's stage then.
    run["steady_from"] = {"0": {"joint": 600}}
    run["alarms"] += [{"joint": 0, "cycle": 650, "quantity": "joint", "stage": None, "wear": 0.0},
                      {"joint": 0, "cycle": 590, "quantity": "joint", "stage": None, "wear": 0.0},
                      {"joint": 0, "cycle": 800, "quantity": "kl_weighted", "stage": None, "wear": 0.0}]
    counts = watching_study.false_alarms([run], 1000.0)
    assert counts["steady"]["alarms"] == 1 and counts["warm-up"]["alarms"] == 3


def test_thermal_filter_study_scores_the_filter_against_the_truth():
    """thermal_filter_study on synthetic rows: a joint warming by the thermal law with readings 2 °C noisy and an
    overnight stop. The filter's rms error is below the readings' 2 °C and the former smoothing's; a reading column
    equal to the truth plus a constant would score 0 (offsets are removed)."""
    import thermal_filter_study

    from sim_controller.thermal import ThermalModel

    rng = np.random.default_rng(5)
    model, rows, t = ThermalModel(temperature=30.0, ambient=30.0), [], 0.0
    for k in range(600):
        if k == 300:
            model.advance(12 * 3600.0, 0.0)
            t += 12 * 3600.0
        p = 7.5 * (1 + 0.1 * rng.standard_normal())
        model.advance(110.0, p)
        rows.append({"power": p, "t_start": t, "t_end": t + 110.0, "truth": model.temperature,
                     "reading": model.temperature + 4.0 + 2.0 * rng.standard_normal()})
        t += 110.0
    e = thermal_filter_study.errors(rows, skip=80)
    assert 1.6 < e["reading"]["rms"] < 2.4                  # 2 °C noise, offset removed
    assert e["filter"]["rms"] < e["smoothing"]["rms"] and e["filter"]["rms"] < e["reading"]["rms"] / 2
    exact = [{**r, "reading": r["truth"] + 4.0} for r in rows]
    assert thermal_filter_study.errors(exact, skip=80)["reading"]["rms"] < 1e-9
    # The reading's scale: 1 for an offset alone (noise or not), 0.85 for a reading compressed by 15 %.
    assert thermal_filter_study.errors(exact, skip=80)["reading"]["scale"] == pytest.approx(1.0)
    assert abs(e["reading"]["scale"] - 1.0) < 0.1          # 7 se: 2 °C noise, truth sd 6.5 °C, 520 rows: se 0.014
    compressed = [{**r, "reading": 40.0 + 0.85 * (r["truth"] - 40.0)} for r in rows]
    assert thermal_filter_study.errors(compressed, skip=80)["reading"]["scale"] == pytest.approx(0.85)


def test_the_shape_of_the_tested_values_tells_a_gaussian_from_a_skewed_or_wandering_series():
    """On 20 000 independent Gaussian values: skewness 0, 2.28 % above 2 sd and variance ratios 1, each within 4
    of its standard errors (skewness √(6/n), the share √(p(1 − p)/n), a ratio of m means ≈ √(2/m)). The other
    side: a left-skewed series (minus a gamma of shape 4: skewness −1) has a light upper tail, and an AR(1) series
    of coefficient 0.7 variance ratios near (1 + φ)/(1 − φ) ≈ 5.7 (4.2 and 5.2 at k = 10, 30)."""
    rng = np.random.default_rng(8)
    n = 20_000
    gauss = temperature_law_study.shape(rng.normal(size=n))
    assert abs(gauss["skewness"]) < 4 * math.sqrt(6 / n)
    assert abs(gauss["above_2sd"] - 0.02275) < 4 * math.sqrt(0.0228 * 0.9772 / n)
    for k in (10, 30):
        assert abs(gauss[f"ratio_{k}"] - 1.0) < 4 * math.sqrt(2 / (n // k))
    skewed = temperature_law_study.shape(-rng.gamma(4.0, size=n))
    assert skewed["skewness"] < -0.8 and skewed["above_2sd"] < 0.01
    ar = np.zeros(n)
    for t in range(1, n):
        ar[t] = 0.7 * ar[t - 1] + rng.normal()
    wandering = temperature_law_study.shape(ar)
    assert wandering["ratio_10"] > 3.5 and wandering["ratio_30"] > 4.5
    assert math.isnan(temperature_law_study.shape(np.zeros(50))["skewness"])


@pytest.mark.parametrize("step", [0.0, 3.0])
def test_the_ramp_trace_finds_a_wear_score_step_and_stays_quiet_without_it(step):
    """tools/studies/ramp_trace.py's replay: a joint at a constant 40 °C whose wear score is N(0, 1) and, from cycle
    150 of 250, ``step`` above it. Without the step no detector may alarm (the shipped budget's run length is 2.6·10⁶
    cycles; 170 monitored cycles); with a 3 σ step the wear score's GLR passes its ≈ 15-nat threshold within
    ≈ 2·15/3² ≈ 4 cycles, so its first alarm falls in 150–170. Its standardised values are those of the nominal:
    the mean of 50 before the step is 0 within 4 standard errors (the nominal's mean from 60 values, 1/√60, and the
    50 values' own, 1/√50: combined 0.19, so ±0.77)."""

    rng = np.random.default_rng(5)
    rows = [{"cycle": c, "motor_temperature": 40.0, "temperature": 40.0, "wear": 0.0,
             "wear_score": float(rng.normal() + (step if c >= 150 else 0.0)),
             "kl_raw": math.exp(rng.normal(-3.0, 0.3)), "kl_weighted": math.exp(rng.normal(-4.0, 0.3))}
            for c in range(250)]
    traced, first = ramp_trace.trace(rows, 1)
    assert len(traced) == 250
    if step == 0.0:
        assert first is None
    else:
        assert first is not None and 150 <= first <= 170, first
    before = [r["z"] for r in traced if 100 <= r["cycle"] < 150]
    assert abs(float(np.mean(before))) < 0.77
    assert "wear" in ramp_trace.block_line(traced[100:110])
