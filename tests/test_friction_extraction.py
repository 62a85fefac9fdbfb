"""Plateau detection and friction extraction on synthetic back-and-forth profiles."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from edge_monitor.features.friction_extraction import FrictionExtractor
from edge_monitor.features.segmentation import PlateauConfig, PlateauDetector
from joint_model import DEFAULT_SPEED_LEVELS
from joint_model.friction import friction_magnitude

from synthetic_frames import cycle_profile, cycle_torque

SPEEDS = DEFAULT_SPEED_LEVELS


def back_and_forth(speeds, *, hold_s=1.2, ramp_s=0.1, pause_s=0.1, inertia=2e-4, gravity=0.3,
                   load=0.5, temperature=40.0, wear=0.0, noise=2e-3, seed=0):
    """Speed and torque of the friction part of a test cycle (no production motion)."""
    speed, _ = cycle_profile(speeds, hold_s, ramp_s, pause_s, production=False)
    torque = cycle_torque(speed, np.random.default_rng(seed), load, temperature, wear, noise, inertia, gravity)
    return speed, torque


def run_extraction(speed, torque, block=256, config=None, segment=None):
    config = config or PlateauConfig(speeds=SPEEDS)
    det = PlateauDetector(config)
    ext = FrictionExtractor(config.speeds)
    tick = np.arange(speed.size)
    for s in range(0, speed.size, block):
        seg = None if segment is None else segment[s:s + block]
        for p in det.update(tick[s:s + block], speed[s:s + block], torque[s:s + block], seg):
            ext.update(p)
    for p in det.flush():
        ext.update(p)
    return det, ext.end_cycle()


def test_extracts_model_friction_at_every_level():
    speed, torque = back_and_forth(SPEEDS, wear=20.0)
    det, curve = run_extraction(speed, torque)
    assert curve.speeds == sorted(SPEEDS)
    truth = friction_magnitude(np.array(curve.speeds), 0.5, 40.0, 20.0)
    err = np.array(curve.torque) - truth
    se = np.array(curve.stderr)
    # Noise 2e-3 over ~470 steady samples per direction: stderr ≈ 2e-3/√470/√2 ≈ 6.5e-5. Allow 5 σ.
    assert np.all(se > 0) and np.all(se < 2e-4)
    assert np.all(np.abs(err) < 5 * se + 1e-6), err / se
    assert det.counters.plateaus == 2 * len(SPEEDS)
    assert det.counters.cut_short == 0


@settings(max_examples=15, deadline=None)
@given(block=st.integers(min_value=1, max_value=2000))
def test_result_does_not_depend_on_block_size(block):
    speed, torque = back_and_forth(SPEEDS[:4], seed=3)
    _, ref = run_extraction(speed, torque, block=len(speed))
    _, curve = run_extraction(speed, torque, block=block)
    assert curve.speeds == ref.speeds
    np.testing.assert_allclose(curve.torque, ref.torque, rtol=0, atol=1e-12)
    np.testing.assert_allclose(curve.stderr, ref.stderr, rtol=1e-9)


def test_missing_reverse_direction_is_skipped_and_counted():
    speed, torque = back_and_forth([SPEEDS[3]])
    half = speed.size // 2          # forward half only
    det, curve = run_extraction(speed[:half], torque[:half])
    assert curve.n_points == 0
    assert curve.skipped == {"missing reverse direction": 1}


def test_short_plateau_is_cut_short_and_unknown_speed_is_counted():
    speed_short, torque_short = back_and_forth([SPEEDS[5]], hold_s=0.4)
    speed_odd, torque_odd = back_and_forth([60.0], hold_s=1.0)
    det, curve = run_extraction(np.concatenate([speed_short, speed_odd]),
                                np.concatenate([torque_short, torque_odd]))
    assert curve.n_points == 0
    assert det.counters.cut_short == 2
    assert det.counters.unmatched == 2


def test_nonfinite_samples_are_counted_not_averaged():
    speed, torque = back_and_forth([SPEEDS[7]])
    torque[300:310] = np.nan
    det, curve = run_extraction(speed, torque)
    assert det.counters.nonfinite_samples == 10
    assert curve.n_points == 1 and np.isfinite(curve.torque[0])


def test_config_rejects_bad_speeds():
    with pytest.raises(ValueError, match="segmentation.speeds"):
        PlateauConfig(speeds=(1.0, -2.0))
    with pytest.raises(ValueError, match="segmentation.speeds"):
        PlateauConfig(speeds=(3.0, 3.0))


@pytest.mark.parametrize("value", [10**400, float("nan"), float("inf"), True, "0.3", -1.0])
def test_config_rejects_a_tolerance_that_is_no_finite_number(value):
    with pytest.raises(ValueError, match="segmentation.tolerance_abs: must be a finite number >= 0"):
        PlateauConfig(tolerance_abs=value)


def _plateaus(speed, torque, segment, block):
    det = PlateauDetector(PlateauConfig())
    tick = np.arange(speed.size)
    out = []
    for s in range(0, speed.size, block):
        seg = None if segment is None else segment[s:s + block]
        out += det.update(tick[s:s + block], speed[s:s + block], torque[s:s + block], seg)
    return [(p.level, p.direction, p.n, p.tick_start, p.tick_end) for p in out + det.flush()], det.level_speeds


def _two_automatic_cycles(codes: bool):
    speed, segment = cycle_profile(SPEEDS[:4], production=codes)
    torque = cycle_torque(speed, np.random.default_rng(6))
    return np.tile(speed, 2), np.tile(torque, 2), np.tile(segment, 2) if codes else None


_SAMPLE_BY_SAMPLE: dict[bool, tuple] = {}


@settings(max_examples=12, deadline=None)
@given(block=st.integers(min_value=2, max_value=3000), codes=st.booleans())
def test_automatic_levels_do_not_depend_on_block_size(block, codes):
    """Without configured speeds a finished plateau changes how later samples are labelled (the level's
    measured speed; a discovered level). The samples after it in the same block are labelled again, so
    any cutting into blocks gives the plateaus of a sample-by-sample stream (the agent gathers 512
    samples per joint live and thousands in a replay)."""
    speed, torque, segment = _two_automatic_cycles(codes)
    if codes not in _SAMPLE_BY_SAMPLE:
        _SAMPLE_BY_SAMPLE[codes] = _plateaus(speed, torque, segment, 1)
    plateaus, levels = _plateaus(speed, torque, segment, block)
    assert plateaus == _SAMPLE_BY_SAMPLE[codes][0]
    np.testing.assert_allclose(levels, _SAMPLE_BY_SAMPLE[codes][1], rtol=1e-12)
    assert len(plateaus) >= 2 * 4     # the second cycle, both directions (the first finds the levels)


def test_levels_from_the_segment_codes_need_no_configured_speeds():
    """Speed level k is segment k + 1: the datum's speed is the measured plateau speed (the speeds
    of an experiment design, say, reach the agent without any configuration)."""
    speeds = (33.682, 38.682, 43.682)          # closer together than the default levels' bands
    speed, segment = cycle_profile(speeds, production=True)
    torque = cycle_torque(speed, np.random.default_rng(4), temperature=40.0)
    det, curve = run_extraction(speed, torque, config=PlateauConfig(), segment=segment)
    assert curve.speeds == pytest.approx(speeds, abs=1e-3)
    truth = friction_magnitude(np.array(speeds), 0.5, 40.0)
    assert np.all(np.abs(np.array(curve.torque) - truth) < 6 * np.array(curve.stderr) + 5e-5)
    assert det.counters.plateaus == 6


def test_without_segments_or_speeds_levels_are_discovered_from_steady_runs():
    speed, _ = cycle_profile(SPEEDS[:4], production=False)
    torque = cycle_torque(speed, np.random.default_rng(5))
    two_cycles_speed, two_cycles_torque = np.tile(speed, 2), np.tile(torque, 2)
    det, curve = run_extraction(two_cycles_speed, two_cycles_torque, config=PlateauConfig())
    # a level's speed is the mean speed of its first steady run: within the level band (2 % + 0.3 rad/s)
    band = 0.02 * np.array(SPEEDS[:4]) + 0.3
    assert np.all(np.abs(np.sort(det.level_speeds) - SPEEDS[:4]) <= band)
    assert det.counters.levels_discovered == 4
    assert np.all(np.abs(np.array(curve.speeds) - SPEEDS[:4]) <= band)     # the second cycle's data


def _cut_into(speed, segment, config, blocks):
    """Plateaus, counters and discovered levels of a stream fed in blocks of ``blocks`` samples (100 Hz)."""
    det = PlateauDetector(config, rate_hz=100.0)
    speed = np.asarray(speed, dtype=float)
    torque = 0.1 * np.sign(speed)
    tick = np.arange(speed.size)
    out = []
    for s in range(0, speed.size, blocks):
        seg = None if segment is None else np.asarray(segment[s:s + blocks])
        out += det.update(tick[s:s + blocks], speed[s:s + blocks], torque[s:s + blocks], seg)
    out += det.flush()
    return [(p.level, p.direction, p.n, p.tick_start) for p in out], det.counters.as_dict(), det.level_speeds


SHORT = dict(settle_s=0.03, guard_s=0.02, min_steady_s=0.03)


@pytest.mark.parametrize("speeds, speed, segment", [
    # a one-sample run right after the level's speed was measured: the samples after it are labelled anew
    ((), [10.0] * 10 + [12.0] * 11 + [0.0] * 2, [1] * 21 + [0] * 2),
    # the same after a discovered level (no segment codes)
    ((), [40.0] * 10 + [40.5] * 10 + [0.0, 0.0], None),
    # a production sample inside the outer band is on no level, and the hysteresis cannot carry across it
    ((10.0,), [10.0] * 3 + [10.6] * 12 + [0.0] * 3, [200] * 3 + [1] * 12 + [0] * 3),
], ids=["measured speed", "discovered level", "production sample"])
def test_block_boundaries_found_by_review_give_the_sample_by_sample_result(speeds, speed, segment):
    """Counterexamples a brute-force comparison with one-sample blocks found (2026-11-24)."""
    config = PlateauConfig(speeds=speeds, tolerance_rel=1e-6 if not speeds and segment else 0.02, **SHORT)
    assert _cut_into(speed, segment, config, len(speed)) == _cut_into(speed, segment, config, 1)
