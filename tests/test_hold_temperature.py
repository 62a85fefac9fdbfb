"""The smoothed temperature the detectors' holds read (edge_monitor/pipeline/hold_temperature.py): it shrinks
the cycle-to-cycle scatter by the factor exponential smoothing gives, follows a stop at once, lets one
wild reading move one cycle only, and survives a restart."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from edge_monitor.pipeline.hold_temperature import MIN_JUMP, HoldTemperature

#: The simulator's cycle-mean motor temperature scatter [°C].
NOISE = 3.0


def _feed(h: HoldTemperature, readings) -> list[float | None]:
    return [h.update(float(t)) for t in readings]


def test_the_smoothing_shrinks_the_scatter_by_its_derived_factor() -> None:
    """White scatter σ through an exponential smoothing a: the level's std is σ·√(a/(2 − a)) (1.134 °C
    for 3 °C at a = 0.25). Over 4 000 cycles the level's lag-1 correlation 1 − a leaves ≈ 4 000·a/(2 − a)
    = 571 independent values, so the sample std is within ≈ 1/√(2·571) = 3 % of it; 4 of those is 12 %.
    (A reading beyond 3 residual stds, ≈ 0.3 % of Gaussian ones, is its cycle's temperature and stays out
    of the level unless the next one confirms it; the scatter is not a jump, so the level hardly moves.)"""
    rng = np.random.default_rng(1)
    h = HoldTemperature()
    levels = []
    for t in 50.0 + rng.normal(0.0, NOISE, 4100):
        h.update(float(t))
        levels.append(h.level)
    out = np.array(levels[100:])
    expected = NOISE * math.sqrt(h.smoothing / (2.0 - h.smoothing))
    assert float(np.std(out)) == pytest.approx(expected, rel=0.12)
    assert float(np.mean(out)) == pytest.approx(50.0, abs=4 * expected / math.sqrt(571))


def test_a_stop_is_followed_at_once_and_a_glitch_moves_one_cycle_only() -> None:
    """A warm joint (60 ± 3 °C) stops overnight and restarts at 30 °C: the first cold reading is that
    cycle's temperature, the second confirms the stop (one jump and one stop counted) and the smoothing goes
    on from there. Other side: one reading 40 °C off in a steady stream is that cycle's temperature only; the
    next cycle is back where the smoothing was and no jump is counted."""
    rng = np.random.default_rng(2)
    h = HoldTemperature()
    _feed(h, 60.0 + rng.normal(0.0, NOISE, 200))
    first, second = 31.0, 29.5
    assert h.update(first) == first and h.jumps == 0
    assert h.update(second) == pytest.approx(0.5 * (first + second)) and h.jumps == h.stops == 1
    after = _feed(h, 30.0 + rng.normal(0.0, NOISE, 20))
    assert all(25.0 < t < 35.0 for t in after)
    level = h.level
    assert h.update(level + 40.0) == level + 40.0                 # the glitch's own cycle
    back = h.update(level)
    assert back == pytest.approx(level) and h.jumps == 1 and h.pending is None


def test_scatter_alone_hardly_counts_a_stop() -> None:
    """A counted stop needs two consecutive residuals beyond 3 of their std, both down and agreeing:
    ≈ (1.3·10⁻³)² per cycle for Gaussian scatter, measured 26 per 10⁶ cycles (Student-t with 5 degrees of
    freedom and the same std: 207 per 10⁶), so ≈ 0.5 expected in 20 000 cycles; the Poisson probability of
    3 or more is 1.4 %. One wild reading alone is followed for its cycle, never counted."""
    rng = np.random.default_rng(3)
    h = HoldTemperature()
    _feed(h, 45.0 + rng.normal(0.0, NOISE, 20_000))
    assert h.stops <= 2


def test_a_steady_sensor_still_needs_a_jump_of_the_floor() -> None:
    """A sensor without scatter: its spread is ≈ 0, so the floor :data:`MIN_JUMP` decides what is a jump:
    a 1 °C step is smoothed, a 5 °C drop held twice is a stop."""
    h = HoldTemperature()
    _feed(h, [50.0] * 20)
    assert h.update(51.0) == pytest.approx(50.25) and h.pending is None
    _feed(h, [51.0] * 20)
    _feed(h, [46.0, 46.0])
    assert h.jumps == h.stops == 1 and h.level == pytest.approx(46.0)
    _feed(h, [46.0] * 20 + [52.0, 52.0])                 # a jump up is followed too, but is no stop
    assert h.jumps == 2 and h.stops == 1 and h.level == pytest.approx(52.0)
    assert MIN_JUMP <= 5.0


def test_an_unknown_temperature_is_none_and_changes_nothing() -> None:
    h = HoldTemperature()
    _feed(h, [40.0, 41.0, 42.0])
    before = h.state_dict()
    assert h.update(None) is None and h.update(math.nan) is None and h.update(math.inf) is None
    assert h.state_dict() == before


@settings(max_examples=60, deadline=None)
@given(st.lists(st.floats(-40.0, 150.0), min_size=1, max_size=80), st.integers(0, 79))
def test_a_saved_state_continues_identically(readings: list[float], cut: int) -> None:
    """Saved at any cycle (strict JSON) and restored, it gives the same outputs as the one that ran on."""
    cut = min(cut, len(readings))
    h = HoldTemperature()
    _feed(h, readings[:cut])
    restored = HoldTemperature.from_state(json.loads(json.dumps(h.state_dict(), allow_nan=False)))
    assert _feed(restored, readings[cut:]) == _feed(h, readings[cut:])


@pytest.mark.parametrize("state", [None, [], {}, {"level": "hot"}, {"level": 50.0, "variance": -1.0, "readings": 3},
                                   {"level": math.inf, "variance": 1.0, "readings": 3},
                                   {"level": 50.0, "variance": 1.0, "readings": True},
                                   {"level": 50.0, "variance": 1.0, "readings": -2}])
def test_a_damaged_state_starts_afresh(state) -> None:
    h = HoldTemperature.from_state(state)
    assert h.level is None and h.readings == 0 and h.update(40.0) == 40.0


def test_a_damaged_pending_or_count_is_dropped_and_the_level_kept() -> None:
    h = HoldTemperature.from_state({"level": 50.0, "variance": 4.0, "readings": 10, "pending": "x", "jumps": -1,
                                    "stops": 1.5})
    assert h.level == 50.0 and h.pending is None and h.jumps == h.stops == 0


@pytest.mark.parametrize("state", [{"level": 10 ** 400, "variance": 1.0, "readings": 3},
                                   {"level": 1e15, "variance": 1.0, "readings": 3},
                                   {"level": 50.0, "variance": 1e15, "readings": 3},
                                   {"level": 50.0, "variance": 10 ** 400, "readings": 3}])
def test_an_implausible_or_overflowing_state_starts_afresh(state) -> None:
    """Beyond a float, beyond −100 … 300 °C or a spread beyond 1 000 °C: afresh, never an exception."""
    h = HoldTemperature.from_state(state)
    assert h.level is None and h.update(40.0) == 40.0


def test_a_state_saved_before_the_smoothing_is_replayed_from_recent_temperatures() -> None:
    """The last temperatures of the settling test give the smoothing its level and spread, so a stop
    right after an upgrade is still seen (counted from zero)."""
    rng = np.random.default_rng(4)
    h = HoldTemperature.replayed(list(55.0 + rng.normal(0.0, NOISE, 240)))
    assert h.level == pytest.approx(55.0, abs=4 * NOISE * math.sqrt(0.25 / 1.75)) and h.readings >= 32
    assert h.jumps == h.stops == 0
    _feed(h, [30.0, 31.0])
    assert h.stops == 1


def test_a_bad_smoothing_is_a_clear_error() -> None:
    for bad in (0.0, -0.1, 1.5):
        with pytest.raises(ValueError, match="smoothing"):
            HoldTemperature(smoothing=bad)


def test_a_lasting_shift_below_a_stop_is_followed_without_restarting_the_settling() -> None:
    """A lasting step of 3.5 residual stds (≈ 10 °C here: a shorter stop, or a cooler program): each
    reading jumps, but the pair's mean is short of the 4 stds a stop needs. The level follows after two
    readings (it never stays stuck on the old level, its readings all pending) and no stop is counted."""
    rng = np.random.default_rng(8)
    h = HoldTemperature()
    _feed(h, 50.0 + rng.normal(0.0, NOISE, 300))
    step = 3.5 * math.sqrt(h.variance)
    after = _feed(h, 50.0 - step + rng.normal(0.0, 0.3, 10))
    assert h.stops == 0 and h.jumps == 1 and h.confirmed
    assert all(t == pytest.approx(50.0 - step, abs=1.5) for t in after)


def test_a_wild_reading_in_the_first_cycles_moves_neither_level_nor_spread() -> None:
    """Before the spread is trusted (32 readings) a jump is a residual beyond 10 °C: one reading of 150 °C
    at the 11th cycle is that cycle's temperature only; an implausible one (6553.5 °C, a raw 0xFFFF) is
    no temperature at all. Neither enters the level nor the spread, and no stop is counted that early."""
    rng = np.random.default_rng(9)
    h = HoldTemperature()
    readings = list(50.0 + rng.normal(0.0, NOISE, 30))
    readings[10], readings[20] = 150.0, 6553.5
    out = _feed(h, readings)
    assert out[10] == 150.0 and out[20] is None
    assert abs(h.level - 50.0) < 4 * NOISE and h.variance < (4 * NOISE) ** 2 and h.stops == 0
