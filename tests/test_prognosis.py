"""The wear-trend models and the prognosis of one joint (docs/PROGNOSIS.md): trends found where there are
some and none where there are none, bands that hold what they claim on the model's own law, the crossing
distributions against their closed forms, state round trips, configuration errors named."""

from __future__ import annotations

import dataclasses
import json
import math

import numpy as np
import pytest
from scipy import stats

from edge_monitor.errors import ConfigError, StateMismatch
from edge_monitor.features.prognosis import JointPrognosis, PrognosisConfig, horizon_key
from edge_monitor.stats.crossing_time import (
    gaussian_crossing_cdf,
    horizon_grid,
    probability_within,
    quantiles,
    wiener_crossing_cdf,
)
from edge_monitor.stats.wear_trend import TREND_MODELS, TrendConfig, new_trend, trend_from_state

CRITICAL = 35.0
#: The std a series of estimates states: the trend takes them to scatter noise_scale times as much, so a
#: series with this std and N(0, (NOISE_SCALE·STATED)²) noise is what the filter assumes.
STATED = 5.0
NOISE = TrendConfig().noise_scale * STATED


def feed(trend, values, start=0):
    for k, value in enumerate(values):
        trend.update(start + k, float(value), STATED)
    return trend


def test_the_crossing_time_of_a_wiener_process_is_inverse_gaussian():
    # known level and drift: P(T ≤ h) is the inverse-Gaussian CDF, mean d/μ, shape d²/σ² (docs/PROGNOSIS.md)
    d, mu, sigma2 = 20.0, 0.05, 0.2
    h = horizon_grid(5000.0, 400)
    cdf = wiener_crossing_cdf(h, CRITICAL, CRITICAL - d, 0.0, mu, 0.0, sigma2)
    mean, shape = d / mu, d * d / sigma2
    exact = stats.invgauss(mean / shape, scale=shape).cdf(h)
    assert np.max(np.abs(cdf - exact)) < 1e-9
    # without drift the process still crosses, later; with a negative drift not always (defective law)
    stalled = wiener_crossing_cdf(h, CRITICAL, CRITICAL - d, 0.0, -0.01, 0.0, sigma2)
    assert stalled[-1] < math.exp(2 * -0.01 * d / sigma2) + 1e-9


def test_the_gaussian_crossing_and_its_quantiles_invert_each_other():
    h = horizon_grid(2000.0, 300)
    mean, var = 10.0 + 0.05 * h, 4.0 + 0.0 * h          # a straight line known up to ±2 wear units
    cdf = gaussian_crossing_cdf(mean, var, CRITICAL)
    p10, median, p90 = quantiles(h, cdf, (0.1, 0.5, 0.9))
    assert median == pytest.approx(25.0 / 0.05, rel=0.01)           # where the mean crosses
    # where mean + z·2 crosses: (25 − 2z)/0.05; the grid's log-linear interpolation is within 1 %
    z = stats.norm.ppf(0.9)
    assert p10 == pytest.approx((25.0 - 2 * z) / 0.05, rel=0.01) and p90 == pytest.approx((25.0 + 2 * z) / 0.05, rel=0.01)
    assert probability_within(h, cdf, median) == pytest.approx(0.5, abs=0.01)
    assert quantiles(h, np.full_like(h, 0.3), (0.5,)) == [None]       # never reached within the grid


def _rates(model: str, slope: float, runs: int, cycles: int, seed: int) -> list[tuple[float, float]]:
    rng = np.random.default_rng(seed)
    config = dataclasses.replace(TrendConfig(), model=model)
    out = []
    for _ in range(runs):
        values = 5.0 + slope * np.arange(cycles) + rng.normal(0.0, NOISE, cycles)
        trend = feed(new_trend(config), values)
        out.append((trend.rate, trend.rate_std))
    return out


@pytest.mark.parametrize("model", ["drifting_rate", "wiener", "accelerating", "multi_rate", "line"])
def test_each_model_finds_the_rate_of_a_linear_wear_within_its_own_uncertainty(model):
    # 40 joints wearing 0.04 per cycle for 400 cycles under the noise each model assumes: the rate's error
    # over its own std is ≈ N(0, 1), so |z| < 4 for all 40 fails with P ≈ 40 · 6e-5 = 0.3 % if the stated
    # std is honest; the mean z within ±4/√40 (4 standard errors of a mean of 40) says it is not biased
    z = np.array([(rate - 0.04) / std for rate, std in _rates(model, 0.04, 40, 400, seed=11)])
    assert np.all(np.abs(z) < 4.0), z
    assert abs(z.mean()) < 4.0 / math.sqrt(40), z.mean()


def _trend_share(model: str, slope: float, seed: int, runs: int = 60, cycles: int = 300, after: int = 0) -> float:
    """Share of the cycles from ``after`` on (and after the trend's learning) in which a prognosis without
    the alarm gate and with trend_sigma = 3 reports a trend."""
    rng = np.random.default_rng(seed)
    config = PrognosisConfig(model=model, after_alarm=False, trend_sigma=3.0)
    found = total = 0
    for _ in range(runs):
        prognosis = JointPrognosis(config, CRITICAL)
        values = 5.0 + slope * np.arange(cycles) + rng.normal(0.0, NOISE, cycles)
        for k, value in enumerate(values):
            forecast = prognosis.update(k, float(value), STATED, use=True, alarm=False, cycles_per_day=300.0)
            if forecast.state != "learning" and k >= after:
                total += 1
                found += forecast.state in ("forecast", "critical")
    return found / total


#: The agent's model runs nine filters: its statistical checks take 8–25 s each here (marked slow).
BOTH = ["drifting_rate", pytest.param("multi_rate", marks=pytest.mark.slow)]


@pytest.mark.parametrize("model", BOTH)
def test_no_trend_is_reported_where_there_is_none(model):
    # a constant wear under the assumed noise: the rate over its std is ≈ N(0, 1) each cycle (for the
    # mixture too: a mixture of calibrated predictions is calibrated), above 3 with P = 0.00135; the
    # drifting-rate filter remembers ≈ 45 cycles (the mixture's members longer), so 60 runs × 270 cycles
    # hold ≤ 360 independent looks: the share's standard error is ≤ √(0.00135 / 360) = 0.002, and 0.01 is
    # 4 of them above
    assert _trend_share(model, 0.0, seed=12) < 0.01


@pytest.mark.parametrize("model, slope, after", [("drifting_rate", 0.2, 150),
                                                  pytest.param("multi_rate", 0.5, 300, marks=pytest.mark.slow)])
def test_a_trend_is_reported_where_there_is_one(model, slope, after):
    # a wear growing by `slope` per cycle: once the model has settled (from cycle `after` on: the filter's
    # rate std has shrunk from its prior to the steady one; the mixture's weights have left the fast
    # filters that win the first cycles) its rate std is below slope/7 (asserted on a series of the same
    # noise), so the rate sits ≥ 7 std above 0 and ≥ 4 std above the 3-std line: a miss in P(Z < −4) =
    # 3e-5 of the cycles
    rng = np.random.default_rng(16)
    values = 5.0 + slope * np.arange(after) + rng.normal(0.0, NOISE, after)
    trend = feed(new_trend(dataclasses.replace(TrendConfig(), model=model)), values)
    assert trend.rate_std < slope / 7
    assert _trend_share(model, slope, seed=13, cycles=after + 150, after=after) > 0.999


@pytest.mark.parametrize("model", BOTH)
def test_the_band_holds_the_remaining_life_as_often_as_it_says_on_a_linear_wear(model):
    # 200 joints on the model's own ground (a constant rate drawn per joint, the assumed noise), one forecast
    # each after 250 cycles: the true remaining life lies in the 10–90 % band in a Binomial(200, p) share;
    # drifting-rate models on a constant rate are conservative (p ≥ 0.8), so the share must be
    # ≥ 0.8 − 3·√(0.8·0.2/200) = 0.715 and, being conservative, not above what a band twice too wide
    # would give: P(|Z| < 2·1.28) = 0.99
    rng = np.random.default_rng(14)
    config = PrognosisConfig(model=model, after_alarm=False)
    held = 0
    for _ in range(200):
        rate = rng.uniform(0.03, 0.08)
        prognosis = JointPrognosis(config, CRITICAL)
        values = 2.0 + rate * np.arange(250) + rng.normal(0.0, NOISE, 250)
        for k, value in enumerate(values):
            forecast = prognosis.update(k, float(value), STATED, use=True, alarm=True, cycles_per_day=300.0)
        remaining = (CRITICAL - 2.0) / rate - 249
        if forecast.state != "forecast" or forecast.cycles is None:     # no trend found: holds no finite life
            continue
        p10, _, p90 = forecast.cycles
        held += p10 is not None and p10 <= remaining and (p90 is None or remaining <= p90)
    assert 0.715 <= held / 200 <= 0.99


@pytest.mark.parametrize("model", TREND_MODELS)
def test_a_trend_survives_a_round_trip_through_json(model):
    config = dataclasses.replace(TrendConfig(), model=model)
    rng = np.random.default_rng(15)
    values = 3.0 + 0.05 * np.arange(150) + rng.normal(0.0, NOISE, 150)
    trend = feed(new_trend(config), values)
    restored = trend_from_state(config, json.loads(json.dumps(trend.state_dict())))
    more = values[-1] + 0.05 * np.arange(1, 40) + rng.normal(0.0, NOISE, 39)
    feed(trend, more, start=150)
    feed(restored, more, start=150)
    h = horizon_grid(1e4)
    assert restored.level == trend.level and restored.rate == trend.rate
    assert np.array_equal(restored.crossing_cdf(CRITICAL, h), trend.crossing_cdf(CRITICAL, h))
    other = dataclasses.replace(config, level_diffusion=0.5)
    with pytest.raises(StateMismatch):
        trend_from_state(other, trend.state_dict())


def test_the_prognosis_state_round_trips_and_a_reset_starts_learning_again():
    config = PrognosisConfig(learning_cycles=5, warning_probability=0.5)
    prognosis = JointPrognosis(config, CRITICAL)
    for k in range(60):
        forecast = prognosis.update(k, 10.0 + 0.3 * k, STATED, use=True, alarm=True, cycles_per_day=300.0)
        prognosis.warning_change(forecast)
    assert forecast.state == "forecast" and prognosis.warning
    restored = JointPrognosis.from_state(config, CRITICAL, json.loads(json.dumps(prognosis.state_dict())))
    again = restored.update(60, 28.0, STATED, use=True, alarm=True, cycles_per_day=300.0)
    once = prognosis.update(60, 28.0, STATED, use=True, alarm=True, cycles_per_day=300.0)
    assert again.section() == once.section() and restored.warning
    prognosis.reset()
    assert prognosis.update(61, 28.0, STATED, use=True, alarm=True, cycles_per_day=300.0).state == "learning"
    assert not prognosis.warning


def test_states_and_what_each_publishes():
    config = PrognosisConfig(learning_cycles=5)
    p = JointPrognosis(config, CRITICAL)
    first = p.update(0, 5.0, STATED, use=True, alarm=False, cycles_per_day=300.0).section()
    assert first["state"] == "learning" and first["p_critical"] == {"7": None, "30": None}
    assert p.update(1, None, None, use=True, alarm=False, cycles_per_day=300.0).state == "learning"
    for k in range(2, 40):                           # rising, but no alarm: the gate keeps it "no trend"
        section = p.update(k, 5.0 + 0.5 * k, STATED, use=True, alarm=False, cycles_per_day=300.0).section()
    assert section["state"] == "no_trend" and section["beyond_horizon"] and section["days"] is None
    assert "no growing wear found" in section["text"]
    section = p.update(40, 25.0, STATED, use=True, alarm=True, cycles_per_day=300.0).section()
    assert section["state"] == "forecast" and not section["beyond_horizon"]
    assert 0 < section["days"]["p10"] < section["days"]["median"] < section["days"]["p90"]
    assert section["cycles"]["median"] == pytest.approx(300.0 * section["days"]["median"], rel=0.01)
    assert section["p_critical"]["30"] >= section["p_critical"]["7"] > 0.5 and "about" in section["text"]
    for k in range(41, 80):
        section = p.update(k, 5.0 + 0.5 * k, STATED, use=True, alarm=True, cycles_per_day=300.0).section()
    assert section["state"] == "critical" and section["cycles"] is None and "reached" in section["text"]


def test_a_slow_wear_is_beyond_the_horizon_and_says_so():
    # 0.001 per cycle at 300 cycles a day: 0.3 a day, ≈ 100 days to go from 5 to 35 with a 30-day horizon
    # (any rate above 0 is a trend here: the test is about what a slow one publishes)
    p = JointPrognosis(PrognosisConfig(learning_cycles=5, trend_sigma=0.0), CRITICAL)
    for k in range(400):
        section = p.update(k, 5.0 + 0.001 * k, 0.2, use=True, alarm=True, cycles_per_day=300.0).section()
    assert section["state"] == "forecast" and section["beyond_horizon"] is True
    assert section["cycles"] is None and section["days"] is None
    assert "beyond the 30-day horizon" in section["text"] and section["p_critical"]["30"] < 0.5


def test_cycles_not_used_move_the_trend_on_without_feeding_it():
    p = JointPrognosis(PrognosisConfig(learning_cycles=3), CRITICAL)
    for k in range(10):
        p.update(k, 50.0, STATED, use=False, alarm=True, cycles_per_day=300.0)     # the joint model learns
    assert p.trend.updates == 0


@pytest.mark.parametrize("field, value, message", [
    ("model", "kalman", "prognosis.model: must be one of"),
    ("horizons_days", (7.0, 7.0), "prognosis.horizons_days"),
    ("horizons_days", (), "prognosis.horizons_days"),
    ("horizons_days", (10 ** 400,), "prognosis.horizons_days"),
    ("rate_drift", -1.0, "prognosis.rate_drift"),
    ("rate_drifts", (1e-7, float("nan")), "prognosis.rate_drifts"),
    ("warning_probability", 1.0, "prognosis.warning_probability"),
    ("learning_cycles", 1, "prognosis.learning_cycles"),
    ("window", 2, "prognosis.window"),
    ("wear_input", "mode", "prognosis.wear_input"),
])
def test_bad_settings_are_refused_by_name(field, value, message):
    with pytest.raises(ConfigError, match=message):
        PrognosisConfig(**{field: value})


def test_horizon_keys_read_like_the_configured_days():
    assert [horizon_key(d) for d in (7.0, 30, 0.5)] == ["7", "30", "0.5"]
