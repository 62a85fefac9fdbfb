"""Fault injection: every kind is injected and its counter equals the frames actually altered."""

from __future__ import annotations

import numpy as np
import pytest
from test_sim_support import collect, decode

from protocol import frames as pf
from sim_controller.config import SimConfig
from sim_controller.controller import Controller
from sim_controller.faults import FaultInjector, FaultSpec, FaultSpecError, FrameBlock

N = 20_000
BLOCK = 1_000


def synthetic_stream() -> FrameBlock:
    """Frames with unique payloads: byte 1 = counter, bytes 2..7 = frame index; 1 ms apart."""
    index = np.arange(N, dtype=np.uint64)
    data = np.zeros((N, 8), dtype=np.uint8)
    data[:, 1] = index % 256
    data[:, 2:] = (index[:, None] >> (8 * np.arange(6, dtype=np.uint64))).astype(np.uint8)
    ids = pf.MOTOR_STATE_BASE_ID + (np.arange(N) % 3)
    data[:, 0] = pf.frame_crc_block(ids, data)
    return FrameBlock(ids.astype(np.int64), data, np.arange(N) * 1e-3)


def inject(spec: str, seed: int = 1) -> tuple[FrameBlock, FrameBlock, dict[str, int]]:
    clean = synthetic_stream()
    injector = FaultInjector(FaultSpec.parse(spec), np.random.default_rng(seed), pf.frame_crc_block)
    parts = [injector.apply(clean.take(np.arange(i, i + BLOCK))) for i in range(0, N, BLOCK)]
    return clean, FrameBlock.concat(parts + [injector.flush()]), injector.counts


def frame_index(block: FrameBlock) -> np.ndarray:
    return (block.data[:, 2:].astype(np.uint64) << (8 * np.arange(6, dtype=np.uint64))).sum(axis=1).astype(np.int64)


def others_zero(counts: dict[str, int], *keep: str) -> bool:
    return all(v == 0 for k, v in counts.items() if k not in keep)


def test_drop_counts_missing_frames():
    clean, out, counts = inject("drop=0.01")
    assert counts["dropped"] > 0 and others_zero(counts, "dropped")
    idx = frame_index(out)
    assert np.all(np.diff(idx) > 0)
    assert N - len(out) == counts["dropped"]


def test_duplicate_counts_repeated_frames():
    clean, out, counts = inject("duplicate=0.01")
    idx = frame_index(out)
    assert counts["duplicated"] > 0 and others_zero(counts, "duplicated")
    assert int(np.sum(idx[1:] == idx[:-1])) == counts["duplicated"] == len(out) - N
    assert np.all(np.diff(out.timestamps) > 0)


def test_reorder_counts_swapped_pairs():
    clean, out, counts = inject("reorder=0.01")
    idx = frame_index(out)
    assert counts["reordered"] > 0 and others_zero(counts, "reordered")
    assert int(np.sum(np.diff(idx) < 0)) == counts["reordered"]
    assert sorted(idx.tolist()) == list(range(N))
    assert np.array_equal(out.timestamps, clean.timestamps)   # arrival order changed, not the clock


def test_corrupt_flips_one_to_three_bits_and_breaks_the_crc():
    clean, out, counts = inject("corrupt=0.01")
    assert counts["corrupted"] > 0 and others_zero(counts, "corrupted")
    flipped = np.unpackbits(clean.data ^ out.data, axis=1).sum(axis=1)
    assert int(np.count_nonzero(flipped)) == counts["corrupted"]
    assert set(flipped[flipped > 0].tolist()) == {1, 2, 3}
    decoded = pf.decode_block(out.ids, out.data, np.full(len(out), 8))
    assert int((~decoded.crc_ok).sum()) == counts["corrupted"]      # CRC-8H2F catches every 1–3 bit error


def test_delay_counts_late_frames_within_delay_max():
    clean, out, counts = inject("delay=0.01,delay_max=0.005")
    assert counts["delayed"] > 0 and others_zero(counts, "delayed")
    assert len(out) == N and np.all(np.diff(out.timestamps) >= 0)
    late = out.timestamps - clean.timestamps[frame_index(out)]
    assert int(np.count_nonzero(late)) == counts["delayed"]
    assert late.min() >= 0 and late.max() <= 0.005


def test_silence_removes_whole_windows():
    clean, out, counts = inject("silence=0.0005,silence_time=0.05")
    assert counts["silences"] > 0 and others_zero(counts, "silences", "silenced")
    idx = frame_index(out)
    assert N - len(out) == counts["silenced"]
    gaps = np.diff(np.concatenate([[-1], idx, [N]])) - 1
    runs = gaps[gaps > 0]
    # 50 ms at 1 frame/ms: 50 frames, 51 when rounding puts the window end just past a frame time
    assert len(runs) == counts["silences"] and runs.max() <= 51


def test_stuck_freezes_the_signal_with_valid_crc_and_running_counter():
    clean, out, counts = inject("stuck=0.0005,stuck_time=0.03")
    assert counts["stuck_periods"] > 0 and others_zero(counts, "stuck", "stuck_periods")
    assert len(out) == N
    changed = np.any(out.data[:, 2:] != clean.data[:, 2:], axis=1)
    assert int(changed.sum()) == counts["stuck"]
    assert np.array_equal(out.data[:, 1], clean.data[:, 1])              # alive counter still runs
    decoded = pf.decode_block(out.ids, out.data, np.full(len(out), 8))
    assert decoded.crc_ok.all()                                          # invisible to E2E


def test_no_faults_changes_nothing():
    clean, out, counts = inject("")
    assert others_zero(counts) and np.array_equal(out.data, clean.data)


def test_controller_restart_resets_tick_and_counters():
    config = SimConfig(joints=2, cycles=4, seed=4, speeds=(20.0,), plateau_time=0.3,
                       faults=FaultSpec(restart=0.5, restart_gap=0.2))
    controller = Controller(config)
    block = collect(controller.frames())
    decoded = decode(block)
    restarts = controller.summary()["faults"]["restarts"]
    assert restarts > 0
    status = decoded.kind == pf.FrameKind.CONTROLLER_STATUS
    ticks = decoded.status_tick[status]
    resets = np.flatnonzero(np.diff(ticks) < 0) + 1
    assert len(resets) + (ticks[0] == 0 and restarts and bool(controller.truth_records()[0]["restart"])) == restarts
    assert np.all(ticks[resets] == 0) and np.all(decoded.counter[status][resets] == 0)
    # the restart gap is a silence on the bus
    t_status = block.timestamps[status]
    assert np.all(t_status[resets] - t_status[resets - 1] >= 0.2)


def test_all_faults_through_the_controller_add_up():
    spec = FaultSpec.parse("drop=0.002,corrupt=0.002,duplicate=0.002,reorder=0.002,delay=0.002,"
                           "silence=0.0002,stuck=0.0002")
    base = dict(joints=3, cycles=2, seed=9, speeds=(10.0, 100.0), plateau_time=0.3)
    clean = collect(Controller(SimConfig(**base)).frames())
    controller = Controller(SimConfig(**base, faults=spec))
    out = collect(controller.frames())
    counts = controller.summary()["faults"]
    for key in ("dropped", "corrupted", "duplicated", "reordered", "delayed", "silenced", "stuck"):
        assert counts[key] > 0, key
    assert len(out) == controller.summary()["frames_sent"]
    assert len(out) == len(clean) - counts["dropped"] - counts["silenced"] + counts["duplicated"]
    decoded = decode(out)
    assert int((~decoded.crc_ok).sum()) == counts["corrupted"]


@pytest.mark.parametrize("text, field", [("drop=1.5", "faults.drop"), ("bogus=1", "unknown kind 'bogus'"),
                                         ("drop", "expected KEY=VALUE"), ("delay_max=0", "faults.delay_max"),
                                         ("corrupt=x", "faults.corrupt")])
def test_bad_fault_specs_name_the_field(text, field):
    with pytest.raises(FaultSpecError, match=field.replace("(", r"\(")):
        FaultSpec.parse(text)
