"""Ingest: controller ticks across long gaps, cycle numbering across agent and controller restarts."""

from __future__ import annotations

import numpy as np

from edge_monitor.sources.ingest import Ingest

from synthetic_frames import make_frames

SPEEDS = (8.7, 41.7)


def joint_ticks(ingest: Ingest, frames, joint: int = 0, block: int = 700) -> np.ndarray:
    ids, data, dlc, ts = frames
    out = []
    for s in range(0, len(ids), block):
        for run in ingest.update(ids[s:s + block], data[s:s + block], dlc[s:s + block], ts[s:s + block]).runs:
            if joint in run.samples:
                out.append(run.samples[joint].tick)
    return np.concatenate(out)


def test_ticks_stay_exact_across_a_silence_longer_than_the_8_bit_counter():
    ids, data, dlc, ts = make_frames(1, joints=(0,), speeds=SPEEDS, seed=3)
    tick_of_row = np.round(ts * 500).astype(int)
    silent = (tick_of_row >= 1000) & (tick_of_row < 1600)          # 600 ticks: > 256, all frames lost
    frames = tuple(a[~silent] for a in (ids, data, dlc, ts))
    ticks = joint_ticks(Ingest(), frames)
    expected = np.unique(tick_of_row[~silent])
    # the E2E receiver rejects the first frame after the gap (jump > max_delta) and resynchronises on the next
    expected = expected[expected != 1600]
    np.testing.assert_array_equal(ticks, expected)


def test_cycle_numbering_continues_after_a_controller_restart_and_an_agent_restart():
    first = make_frames(2, joints=(0,), speeds=SPEEDS, seed=4)
    again = make_frames(2, joints=(0,), speeds=SPEEDS, seed=5)        # controller restarted: cycles 0, 1 again
    ingest = Ingest()
    seen = []
    for frames in (first, again):
        ids, data, dlc, ts = frames
        seen += [r.cycle for r in ingest.update(ids, data, dlc, ts).runs]
    assert sorted(set(seen)) == [0, 1, 2, 3]
    # an agent restart restores the unwrapping state and keeps the numbering
    restored = Ingest()
    restored.load_state(ingest.state_dict())
    ids, data, dlc, ts = make_frames(1, joints=(0,), speeds=SPEEDS, seed=6, first_cycle=2)
    runs = restored.update(ids, data, dlc, ts).runs
    assert [r.cycle for r in runs] == [4] and runs[0].starts_at_boundary is True
