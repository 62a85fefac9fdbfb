"""Pauses in a joint's samples (edge_monitor/pipeline/pauses.py) and the cooling they tell the KL temperature
compensation (edge_monitor/features/temperature_compensation.py)."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from edge_monitor.features.temperature_compensation import LOOSE_SMOOTHING, TemperatureCompensation
from edge_monitor.pipeline.pauses import PAUSE_S, PauseFinder
from joint_model import FrictionParams

RATE = 500.0


def test_a_block_is_cut_at_its_pauses_and_across_blocks():
    finder = PauseFinder(RATE)
    gap = int(PAUSE_S * RATE)
    ticks = np.r_[np.arange(100), np.arange(100) + 100 + gap, np.arange(50) + 200 + 3 * gap]
    parts = finder.split(ticks)
    assert [(p.start, p.stop) for p, _ in parts] == [(0, 100), (100, 200), (200, 250)]
    assert [pause for _, pause in parts] == pytest.approx([0.0, (gap + 1) / RATE, (2 * gap + 1) / RATE])
    later = finder.split(np.arange(10) + int(ticks[-1]) + 10 * gap)          # the pause before a block
    assert len(later) == 1 and later[0][1] == pytest.approx(10 * gap / RATE)
    assert finder.split(np.arange(10)) == [(slice(0, 10), 0.0)]              # a restart (ticks back): no pause
    again = PauseFinder.from_state(RATE, json.loads(json.dumps(finder.state_dict())))
    assert again.last_tick == finder.last_tick == 9
    assert PauseFinder.from_state(RATE, {"last_tick": "x"}).last_tick is None
    assert finder.split(np.arange(0)) == []


@given(st.lists(st.integers(1, 60_000), min_size=1, max_size=60))
def test_the_runs_cover_the_block_in_order(steps):
    ticks = np.cumsum(steps).astype(np.int64)
    parts = PauseFinder(RATE).split(ticks)
    assert np.concatenate([ticks[p] for p, _ in parts]).tolist() == ticks.tolist()
    assert all(pause == 0.0 or pause >= PAUSE_S for _, pause in parts)
    assert sum(pause > 0 for _, pause in parts) == sum(s >= PAUSE_S * RATE for s in steps[1:])


def test_a_pause_cools_the_compensation_towards_the_idle_temperature():
    """Newton cooling with the thermal time constant: after 16 h (5.3 time constants of 3.04 h) a joint at
    56 °C that idled at 30 °C is within 0.2 °C of 30; after 0.5 h it has cooled 15 % of the way."""
    comp = TemperatureCompensation(FrictionParams())
    for t in [30.0, 30.0, 40.0] + [56.0] * 30:             # the smoothing (0.2) follows the warming
        comp.observe(t)
    warm = comp.current
    assert comp.coldest == pytest.approx(30.0) and warm > 55.0
    comp.cool(0.5 * 3600)
    assert comp.current == pytest.approx(30.0 + (warm - 30.0) * math.exp(-0.5 / 3.04))
    comp.cool(16 * 3600)
    assert comp.current == pytest.approx(30.0, abs=0.2)
    comp.cool(float("nan"))                     # nothing known: nothing changes
    assert comp.current == pytest.approx(30.0, abs=0.2)
    state = json.loads(json.dumps(comp.state_dict()))
    again = TemperatureCompensation(FrictionParams())
    again.load_state(state)
    assert again.coldest == comp.coldest and again.current == comp.current


def test_a_loose_temperature_estimate_is_smoothed_harder():
    """Without a motor temperature the cycle's ξ̂ scatters ±3–6 °C and runs off for a dozen cycles: the
    compensation follows it with weight LOOSE_SMOOTHING (0.1) instead of 0.2. A 6 °C excursion of 12 cycles
    moves the estimate 6·(1 − 0.9¹²) = 4.3 °C (loose) against 6·(1 − 0.8¹²) = 5.6 °C; a steady warming is
    still followed."""
    tight, loose = TemperatureCompensation(FrictionParams()), TemperatureCompensation(FrictionParams())
    for comp, flag in ((tight, False), (loose, True)):
        for _ in range(5):
            comp.observe(56.0, loose=flag)
        for _ in range(12):
            comp.observe(50.0, loose=flag)
    assert 56.0 - tight.current == pytest.approx(6.0 * (1 - 0.8 ** 12))
    assert 56.0 - loose.current == pytest.approx(6.0 * (1 - (1 - LOOSE_SMOOTHING) ** 12))
    for _ in range(200):
        loose.observe(60.0, loose=True)
    assert loose.current == pytest.approx(60.0, abs=0.01)


def test_the_kl_feature_smooths_loosely_only_without_a_motor_temperature():
    """The KL feature passes ``loose`` exactly when the cycle carries no motor temperature (a controller that
    sends none): the same ξ̂ sequence moves its compensation by weight 0.2 with a motor temperature,
    LOOSE_SMOOTHING without."""
    from edge_monitor.features.base import CycleInput
    from edge_monitor.features.friction_extraction import FrictionCurve
    from edge_monitor.features.kl_monitor import KLMonitor

    moved = {}
    for motor in (45.0, None):
        kl = KLMonitor(params=FrictionParams())
        for k, xi in enumerate((50.0, 40.0)):
            cycle = CycleInput(joint=0, cycle=k, t=float(k), friction=FrictionCurve(speeds=[], torque=[], stderr=[]),
                               load_mean=None, load_std=None, motor_temperature=motor, partial=True)
            kl.update(cycle, {"temperature": xi})
        assert kl.compensation is not None
        moved[motor] = 50.0 - kl.compensation.current
    assert moved[45.0] == pytest.approx(0.2 * 10.0) and moved[None] == pytest.approx(LOOSE_SMOOTHING * 10.0)
