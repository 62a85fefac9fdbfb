"""BLF block writer: the private-API block path and its public per-message fallback write the same
file as python-can's own per-message writer."""

from __future__ import annotations

import logging

import can
import numpy as np

from protocol import frames as pf
from sim_controller import log_writers
from sim_controller.faults import FrameBlock
from sim_controller.log_writers import BlockBLFWriter, block_messages, open_block_writer


def _block(n: int = 9000) -> FrameBlock:
    ticks = np.arange(n)
    joints = ticks % 6
    data = pf.encode_motor_state_block(joints, ticks, 0.3 * np.sin(ticks / 40.0), 20 * np.cos(ticks / 90.0),
                                       ticks * 0.01)
    return FrameBlock(pf.MOTOR_STATE_BASE_ID + joints, data, 1.7e9 + 0.3337 + ticks * 0.000333)


def _write(writer, block: FrameBlock, step: int = 2000) -> None:
    for i in range(0, len(block), step):
        writer.write_block(block.take(np.arange(i, min(i + step, len(block)))))
    writer.stop()


def _python_can_bytes(path, block: FrameBlock) -> bytes:
    writer = can.BLFWriter(path, compression_level=log_writers.BLF_COMPRESSION_LEVEL)
    for message in block_messages(block):
        writer.on_message_received(message)
    writer.stop()
    return path.read_bytes()


def test_installed_python_can_takes_the_block_path(tmp_path):
    writer = open_block_writer(tmp_path / "x.blf")
    assert isinstance(writer, BlockBLFWriter) and writer.block_path
    writer.stop()


def test_fallback_writes_the_same_file_and_warns(tmp_path, monkeypatch, caplog):
    block = _block()
    expected = _python_can_bytes(tmp_path / "reference.blf", block)
    fast = open_block_writer(tmp_path / "fast.blf")
    _write(fast, block)
    monkeypatch.setattr(log_writers, "_has_container_buffer", lambda writer: False)  # "internals changed"
    with caplog.at_level(logging.WARNING, logger="sim_controller.log_writers"):
        slow = open_block_writer(tmp_path / "slow.blf")
    assert not slow.block_path and "one message at a time" in caplog.text
    _write(slow, block)
    assert (tmp_path / "fast.blf").read_bytes() == expected
    assert (tmp_path / "slow.blf").read_bytes() == expected
    back = list(can.LogReader(tmp_path / "slow.blf"))
    assert [m.arbitration_id for m in back] == block.ids.tolist()


def test_probe_rejects_a_writer_without_the_container_buffer(tmp_path):
    writer = can.BLFWriter(tmp_path / "y.blf")
    assert log_writers._has_container_buffer(writer)
    writer._buffer = b""            # a different internal representation
    assert not log_writers._has_container_buffer(writer)
    writer._buffer = []
    writer.stop()
