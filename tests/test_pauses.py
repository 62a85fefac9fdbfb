"""Pauses in a joint's samples (edge_monitor/pipeline/pauses.py) and the cooling they tell the KL temperature
compensation (edge_monitor/features/temperature_compensation.py)."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from edge_monitor.features.temperature_compensation import TemperatureCompensation
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
    comp.cool(0.5 * 3600, 3.04 * 3600)
    assert comp.current == pytest.approx(30.0 + (warm - 30.0) * math.exp(-0.5 / 3.04))
    comp.cool(16 * 3600, 3.04 * 3600)
    assert comp.current == pytest.approx(30.0, abs=0.2)
    comp.cool(float("nan"), 3.04 * 3600)                     # nothing known: nothing changes
    assert comp.current == pytest.approx(30.0, abs=0.2)
    state = json.loads(json.dumps(comp.state_dict()))
    again = TemperatureCompensation(FrictionParams())
    again.load_state(state)
    assert again.coldest == comp.coldest and again.current == comp.current
