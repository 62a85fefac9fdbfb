"""The lubricant thermal filter (edge_monitor.features.lubricant_thermal_filter): it tracks a joint's lubricant
through warm-up and stops from its dissipated power and noisy friction readings, a run of readings moved by wear
cannot drag it, a real ambient change still moves it, and its state survives a restart."""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from edge_monitor.features.lubricant_thermal_filter import (
    CLIP,
    CycleHeat,
    LubricantThermalFilter,
    ThermalFilterConfig,
    ThermalObservation,
)
from edge_monitor.features.temperature_compensation import TemperatureCompensation
from joint_model import FrictionParams
from sim_controller.thermal import ThermalModel

CYCLE_S = 110.0          # the plant week's cycle: ≈ 790 cycles a day
READING_STD = 2.0        # the filter's default reading scatter, and the readings' here


def _day(rng: np.random.Generator, *, cycles: int = 400, ambient: float = 30.0, power: float = 7.5,
         stop_h: float = 12.0, bias: np.ndarray | None = None) -> tuple[list[ThermalObservation], np.ndarray]:
    """A cold start, ``cycles`` cycles at ≈ ``power``, a ``stop_h`` stop, ``cycles`` more: the observations the
    filter gets (friction readings = truth + N(0, 2²) + ``bias``) and the true lubricant temperature per cycle."""
    truth_model = ThermalModel(temperature=ambient, ambient=ambient)
    obs, truth = [], []
    for k in range(2 * cycles):
        seconds = CYCLE_S
        if k == cycles:
            truth_model.advance(stop_h * 3600.0, 0.0)
        p = power * (1.0 + 0.1 * rng.standard_normal())
        truth_model.advance(seconds, p)
        reading = truth_model.temperature + READING_STD * rng.standard_normal() + (0.0 if bias is None else bias[k])
        obs.append(ThermalObservation(seconds, p, reading))
        truth.append(truth_model.temperature)
    return obs, np.asarray(truth)


def _run(obs: list[ThermalObservation], stop_at: int | None = None, stop_h: float = 12.0) -> np.ndarray:
    f = LubricantThermalFilter()
    out = []
    for k, o in enumerate(obs):
        if k == stop_at:
            f.cool(stop_h * 3600.0)
        out.append(f.update(o))
    return np.asarray(out, dtype=float)


def _ewma(obs: list[ThermalObservation], weight: float = 0.1) -> np.ndarray:
    out, c = [], None
    for o in obs:
        c = o.temperature if c is None else c + weight * (o.temperature - c)
        out.append(c)
    return np.asarray(out)


def test_tracks_a_warm_up_and_a_stop_better_than_the_readings():
    rng = np.random.default_rng(11)
    obs, truth = _day(rng)
    est = _run(obs, stop_at=400)
    err = est[50:] - truth[50:]
    # The readings scatter by 2 °C; a filter that averages ≥ 4 readings is within 2/√4 = 1 °C rms.
    assert math.sqrt(np.mean(err ** 2)) < READING_STD / 2
    # After the stop the prediction starts from the cooled joint, not from the warm one.
    assert abs(est[400] - truth[400]) < 3 * READING_STD
    assert truth[399] - truth[400] > 15           # the stop really cooled it (≈ 30 → 58 → ≈ 31)


def test_a_run_of_readings_moved_by_wear_barely_moves_it_but_an_ambient_change_does():
    rng = np.random.default_rng(12)
    bias = np.zeros(800)
    bias[300:312] = -6.0                           # a dozen cycles read 6 °C low (docs: what wear and noise did)
    obs, truth = _day(rng, bias=bias)
    est, ewma = _run(obs, stop_at=400), _ewma(obs)
    # Clean reference on the same noise: the dozen-cycle run is the only difference.
    clean_obs, _ = _day(np.random.default_rng(12))
    clean = _run(clean_obs, stop_at=400)
    moved = np.max(np.abs(est[300:320] - clean[300:320]))
    clean_ewma = _ewma(clean_obs)
    moved_ewma = np.max(np.abs(ewma[300:320] - clean_ewma[300:320]))
    assert moved < 0.5 * moved_ewma
    assert moved < 2.0                             # of the 6 °C
    # A true ambient change of +10 °C (every reading stays up) is followed, unlike a transient run.
    rng = np.random.default_rng(13)
    hot_model = ThermalModel(temperature=58.0, ambient=30.0)
    f = LubricantThermalFilter()
    warm_obs, _ = _day(rng, cycles=300, stop_h=0.0)
    for o in warm_obs:
        f.update(o)
    hot_model.temperature = f.temperature
    for _ in range(600):
        hot_model.ambient = 40.0
        hot_model.advance(CYCLE_S, 7.5)
        f.update(ThermalObservation(CYCLE_S, 7.5, hot_model.temperature + READING_STD * rng.standard_normal()))
    assert abs(f.temperature - hot_model.temperature) < 2.0


def test_innovations_are_clipped():
    f = LubricantThermalFilter()
    f.update(ThermalObservation(0.0, 7.5, 40.0))
    before = f.temperature
    s = f.cov[0, 0] + READING_STD ** 2
    f.update(ThermalObservation(0.0, 7.5, before + 1000.0))
    assert f.n_clipped == 1
    assert f.temperature - before <= CLIP * math.sqrt(s) + 1e-9


def test_state_round_trip_and_garbage():
    rng = np.random.default_rng(14)
    obs, _ = _day(rng, cycles=60)
    a = LubricantThermalFilter()
    for o in obs[:70]:
        a.update(o)
    b = LubricantThermalFilter.from_state(a.state_dict())
    for o in obs[70:]:
        assert a.update(o) == b.update(o)
    for junk in (None, {}, {"mean": [1, 2]}, {"mean": [1, 2, 3], "cov": "x"},
                 {"mean": [1, 2, float("nan")], "cov": np.eye(3).tolist()}):
        assert LubricantThermalFilter.from_state(junk).temperature is None
    hostile = {**a.state_dict(), "n_readings": "x", "n_clipped": True}        # counts that are not counts
    restored = LubricantThermalFilter.from_state(hostile)
    assert restored.temperature == a.temperature and restored.n_readings == restored.n_clipped == 0
    a.reset()
    assert a.temperature is None and a.n_readings == 0


def test_missing_readings_predict_and_first_reading_starts():
    f = LubricantThermalFilter(ThermalFilterConfig())
    assert f.update(ThermalObservation(CYCLE_S, 7.5, None)) is None
    assert f.update(ThermalObservation(CYCLE_S, 7.5, 30.0)) == pytest.approx(30.0)
    # No reading: the model warms the joint by itself (K·P = 30 °C above ambient, time constant 3.04 h).
    t = f.update(ThermalObservation(3600.0, 7.5, None))
    assert t == pytest.approx(30.0 + 30.0 * (1 - math.exp(-1 / 3.04)), rel=1e-6)
    assert f.cool(3.04 * 3600.0) < t


def test_cycle_heat():
    h = CycleHeat()
    h.add(np.array([1.0, 2.0, np.nan]), np.array([2.0, 1.0, 1.0]))
    assert h.close(100.0) is None                   # the first cycle: nothing to predict through
    h.add(np.array([1.0, 3.0]), np.array([1.0, 1.0]))
    h.pause(30.0)
    assert h.close(200.0) == (70.0, 2.0)
    assert h.close(300.0) == (100.0, 2.0)          # no samples: the previous cycle's power
    state = h.state_dict()
    assert CycleHeat.from_state(state).state_dict() == state
    assert CycleHeat.from_state({"count": -3, "last_t": "x"}).state_dict()["last_t"] is None


def test_compensation_follows_the_thermal_model_without_motor_temperature():
    comp = TemperatureCompensation(FrictionParams())
    comp.observe(40.0, loose=True, heating=None)            # first cycle: no heat yet, plain smoothing
    assert not comp.follows_thermal and comp.current == 40.0
    comp.observe(40.0, loose=True, heating=(CYCLE_S, 7.5))
    assert comp.follows_thermal and comp.current == pytest.approx(comp.thermal.temperature)
    comp.cool(12 * 3600.0)
    assert comp.current == pytest.approx(comp.thermal.temperature)
    again = TemperatureCompensation(FrictionParams())
    again.load_state(comp.state_dict())
    assert again.follows_thermal and again.current == comp.current
    # With a motor temperature the plain smoothing stays (the motor-temperature path is unchanged).
    motor = TemperatureCompensation(FrictionParams())
    for t in (40.0, 50.0):
        motor.observe(t, loose=False, heating=(CYCLE_S, 7.5))
    assert not motor.follows_thermal and motor.current == pytest.approx(42.0)


@settings(max_examples=60, deadline=None)
@given(st.lists(st.tuples(st.floats(0, 1e5), st.floats(-50, 50), st.one_of(st.none(), st.floats(-60, 200))),
                min_size=1, max_size=40))
def test_any_input_keeps_a_finite_positive_definite_state(steps):
    f = LubricantThermalFilter()
    for seconds, power, reading in steps:
        f.update(ThermalObservation(seconds, power, reading))
    if f.mean is not None:
        assert np.all(np.isfinite(f.mean)) and np.all(np.isfinite(f.cov))
        assert np.all(np.linalg.eigvalsh(f.cov) > -1e-9)


def test_the_kl_feature_feeds_the_thermal_model_its_cycles_power_and_survives_a_restart_mid_cycle():
    """Without a motor temperature and with samples, the KL feature's compensation follows the thermal model,
    fed the cycle's ⟨τ·v⟩ and the controller time between cycle ends less the stops; a monitor restored from
    its state in the middle of a cycle continues exactly as the one that ran on."""
    import json

    from edge_monitor.features.base import CycleInput
    from edge_monitor.features.friction_extraction import FrictionCurve
    from edge_monitor.features.kl_monitor import KLMonitor

    rng = np.random.default_rng(21)
    speed = np.tile(np.r_[np.full(200, 20.0), np.full(200, -20.0)], 3)

    def block(n: int) -> tuple[np.ndarray, np.ndarray]:
        v = speed[:n]
        return 0.05 * np.sign(v) + 0.002 * rng.standard_normal(n), v

    def cycle(k: int, t: float) -> CycleInput:
        return CycleInput(joint=0, cycle=k, t=t, friction=FrictionCurve(speeds=[], torque=[], stderr=[]),
                          load_mean=0.5, load_std=0.05, motor_temperature=None)

    kl = KLMonitor(params=FrictionParams())
    expected_power = []
    for k in range(14):
        tau, v = block(speed.size)
        expected_power.append(float(np.mean(tau * v)))
        kl.update_samples(tau, v)
        if k == 8:
            kl.pause(3600.0)
        out = kl.update(cycle(k, 110.0 * k + (3600.0 if k >= 8 else 0.0)), {"temperature": 40.0 + 0.1 * k})
    comp = kl.compensation
    assert comp is not None and comp.follows_thermal and comp.current == pytest.approx(comp.thermal.temperature)
    assert kl.heat.last_power == pytest.approx(expected_power[-1])
    # What the record shows: the thermal model's temperature, the compensation's reference.
    assert out.section["temperature"] == {"value": comp.current, "reference": comp.reference,
                                          "source": "thermal_model"}
    # Restart in the middle of a cycle: half its samples before, half after.
    tau, v = block(speed.size)
    kl.update_samples(tau[:600], v[:600])
    again = KLMonitor.from_state(kl.config, json.loads(json.dumps(kl.state_dict())), FrictionParams())
    for mon in (kl, again):
        mon.update_samples(tau[600:], v[600:])
    a = kl.update(cycle(14, 110.0 * 14 + 3600.0), {"temperature": 41.5})
    b = again.update(cycle(14, 110.0 * 14 + 3600.0), {"temperature": 41.5})
    assert all(math.isfinite(x) for x in a.values.values()), (a.reason, a.values)
    assert a.values == b.values
    assert again.compensation.current == kl.compensation.current
    # With a motor temperature the compensation smooths the wear estimate's ξ̂.
    kl.update_samples(*block(speed.size))
    motor = kl.update(replace(cycle(15, 110.0 * 15 + 3600.0), motor_temperature=50.0), {"temperature": 41.5})
    assert motor.section["temperature"]["source"] == "smoothed"
    assert motor.section["temperature"]["value"] == pytest.approx(kl.compensation.current)
