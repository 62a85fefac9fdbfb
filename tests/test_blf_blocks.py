"""The vectorised .blf reader gives exactly the frames of python-can's per-message path."""

from __future__ import annotations

from pathlib import Path

import can
import numpy as np
import pytest

from edge_monitor.sources import log_source
from edge_monitor.sources.log_source import LogReport, log_blocks_with_position
from sim_controller.config import SimConfig
from sim_controller.output import record


def _read(path: Path, block_size: int, fast: bool, monkeypatch: pytest.MonkeyPatch) -> tuple[list, dict]:
    with monkeypatch.context() as m:
        if not fast:
            m.setattr(log_source.blf_blocks, "supported", lambda reader: False)
        report = LogReport()
        blocks = [block for block, _ in log_blocks_with_position(path, block_size, report)]
    return blocks, report.to_dict()


def _assert_same(path: Path, block_size: int, monkeypatch: pytest.MonkeyPatch) -> dict:
    fast, fast_report = _read(path, block_size, True, monkeypatch)
    slow, slow_report = _read(path, block_size, False, monkeypatch)
    assert fast_report == slow_report
    assert [len(b[0]) for b in fast] == [len(b[0]) for b in slow]
    for a, b in zip(fast, slow):
        for x, y in zip(a, b):
            assert x.dtype == y.dtype and x.shape == y.shape
            np.testing.assert_array_equal(x, y)
    return fast_report


def _mixed_log(path: Path) -> None:
    """python-can's own writer: standard, extended, remote, short and error frames among plain ones,
    10 µs and ns time stamps are both python-can's choice; an absolute start time."""
    writer = can.BLFWriter(str(path), channel=1)
    rng = np.random.default_rng(5)
    t = 1_700_000_000.0
    for k in range(9000):
        t += float(rng.uniform(1e-5, 1e-3))
        kind = k % 97
        if kind == 3:
            msg = can.Message(timestamp=t, arbitration_id=0x1ABCDE, is_extended_id=True, data=bytes(range(8)))
        elif kind == 5:
            msg = can.Message(timestamp=t, arbitration_id=0x123, is_extended_id=False, is_remote_frame=True, dlc=4)
        elif kind == 7:
            msg = can.Message(timestamp=t, arbitration_id=0x321, is_extended_id=False, data=b"\x01\x02\x03")
        elif kind == 11:
            msg = can.Message(timestamp=t, is_error_frame=True, arbitration_id=0, is_extended_id=False)
        else:
            msg = can.Message(timestamp=t, arbitration_id=0x100 + k % 7, is_extended_id=False,
                              data=rng.integers(0, 256, 8, dtype=np.uint8).tobytes())
        writer.on_message_received(msg)
    writer.stop()


@pytest.mark.parametrize("block_size", [4096, 1000, 7])
def test_simulator_log_same_frames(tmp_path: Path, monkeypatch: pytest.MonkeyPatch, block_size: int) -> None:
    path = tmp_path / "sim.blf"
    record(SimConfig(joints=2, cycles=1, seed=2, speeds=(8.7, 41.7), plateau_time=0.3), path)
    report = _assert_same(path, block_size, monkeypatch)
    assert report["frames"] > 1000 and report["truncated"] is None


def test_mixed_python_can_log_same_frames(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    path = tmp_path / "mixed.blf"
    _mixed_log(path)
    report = _assert_same(path, 512, monkeypatch)
    assert report["frames"] == 9000


@pytest.mark.parametrize("cut", [0.5, 0.9])
def test_cut_and_damaged_logs_same_frames_and_report(tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
                                                     cut: float) -> None:
    """A file cut short: the same frames and report as python-can's path. 64 zero bytes in the middle:
    python-can's path ends there; the vectorised walk reads the same frames up to the damage, skips
    the damaged container (counted) and goes on with the next one."""
    whole = tmp_path / "mixed.blf"
    _mixed_log(whole)
    raw = whole.read_bytes()
    short = tmp_path / "short.blf"
    short.write_bytes(raw[:int(len(raw) * cut)])
    report = _assert_same(short, 512, monkeypatch)
    assert report["truncated"]
    damaged = tmp_path / "damaged.blf"
    middle = int(len(raw) * cut)
    damaged.write_bytes(raw[:middle] + bytes(64) + raw[middle + 64:])
    fast, fast_report = _read(damaged, 512, True, monkeypatch)
    slow, slow_report = _read(damaged, 512, False, monkeypatch)
    assert slow_report["truncated"] and slow_report["frames"] < 9000
    assert fast_report["frames"] > slow_report["frames"]
    assert fast_report["skipped_records"] >= 1 or fast_report["truncated"]
    assert fast_report["frames"] + fast_report["frames_skipped"] >= 9000 or fast_report["truncated"]
    for a, b in zip(_concat(fast), _concat(slow)):
        np.testing.assert_array_equal(a[:len(b)], b)


def _concat(blocks: list) -> list[np.ndarray]:
    return [np.concatenate(column) for column in zip(*blocks)]


def test_object_timestamps_in_10_microsecond_ticks_or_nanoseconds_by_their_flag() -> None:
    """As python-can: object flag 1 counts 10 µs ticks, any other flag nanoseconds."""
    from edge_monitor.sources.blf_blocks import CAN_OBJECT, TIME_TEN_MICS, objects_to_arrays

    objects = np.zeros(2, dtype=CAN_OBJECT)
    objects["flags"] = [TIME_TEN_MICS, 2]
    objects["timestamp"] = [123_456, 123_456_789]
    objects["dlc"] = 8
    ts = objects_to_arrays(objects.tobytes(), 0, 2, 100.0)[3]
    assert ts.tolist() == [100.0 + 123_456 / 1e5, 100.0 + 123_456_789 / 1e9]
