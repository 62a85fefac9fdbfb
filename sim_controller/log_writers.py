"""Block writers for python-can log files: whole frame blocks at once, same bytes as python-can.

Writing one ``can.Message`` at a time costs ≈ 2 µs to create the message plus ≈ 3 µs in
``BLFWriter.on_message_received`` (≈ 1.7 µs for the candump writer) — more than the whole
simulation of a frame, and too slow for the ≥ 50× real-time goal (6 joints at 500 Hz ≈ 3,350
frames per simulated second). So:

* ``.blf``: :class:`BlockBLFWriter` subclasses python-can's ``BLFWriter`` and packs a block of
  CAN_MESSAGE objects with one numpy structured array into the writer's container buffer; the
  writer's own container flushing, compression and header are reused. It relies on
  ``BLFWriter``'s private ``_buffer``/``_buffer_size``/``_flush`` (python-can 4.x);
  tests/test_sim_frames.py checks the file is byte-identical to per-message writing.
* ``.log`` (candump): :class:`BlockCanutilsWriter` formats all lines of a block in one join,
  exactly as ``CanutilsLogWriter`` does.
* anything else ``can.Logger`` supports (``.asc``, ``.csv``, ``.trc``, …): per message.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any, Protocol

import can
import numpy as np
from can.io import blf

from protocol.links import LinkError, is_log_file
from sim_controller.faults import FrameBlock

#: zlib level of BLF containers: 1 (fastest) — level 6 (python-can's default) made compression
#: 60 % of the recording time for ≈ 15 % smaller files.
BLF_COMPRESSION_LEVEL = 1

_CAN_OBJECT = np.dtype([
    ("signature", "S4"), ("header_size", "<u2"), ("header_version", "<u2"), ("object_size", "<u4"),
    ("object_type", "<u4"),                                                     # OBJ_HEADER_BASE
    ("flags", "<u4"), ("client_index", "<u2"), ("object_version", "<u2"), ("timestamp", "<u8"),  # V1
    ("channel", "<u2"), ("msg_flags", "u1"), ("dlc", "u1"), ("arbitration_id", "<u4"), ("data", "u1", (8,)),
])
_HEADER_SIZE = blf.OBJ_HEADER_BASE_STRUCT.size + blf.OBJ_HEADER_V1_STRUCT.size
assert _CAN_OBJECT.itemsize == _HEADER_SIZE + blf.CAN_MSG_STRUCT.size


class BlockWriter(Protocol):
    def write_block(self, block: FrameBlock) -> None: ...
    def stop(self) -> None: ...


class BlockBLFWriter(blf.BLFWriter):
    """``BLFWriter`` with a vectorised :meth:`write_block` (received 11-bit data frames, DLC 8)."""

    def write_block(self, block: FrameBlock) -> None:
        n = len(block)
        if n == 0:
            return
        ts = block.timestamps
        if self.start_timestamp is None:
            self.start_timestamp = int(float(ts[0]) * 1000) / 1000   # as BLFWriter._add_object
        rel = ((ts - self.start_timestamp) * 1e9).astype(np.int64)     # int() truncation, as python-can
        objects = np.zeros(n, dtype=_CAN_OBJECT)
        objects["signature"] = b"LOBJ"
        objects["header_size"] = _HEADER_SIZE
        objects["header_version"] = 1
        objects["object_size"] = _CAN_OBJECT.itemsize
        objects["object_type"] = blf.CAN_MESSAGE
        objects["flags"] = blf.TIME_ONE_NANS
        objects["timestamp"] = np.maximum(rel, 0)
        objects["channel"] = self.channel
        objects["dlc"] = 8
        objects["arbitration_id"] = block.ids
        objects["data"] = block.data
        self._buffer.append(objects.tobytes())
        self._buffer_size += n * _CAN_OBJECT.itemsize
        self.object_count += n
        self.stop_timestamp = float(ts[-1])
        while self._buffer_size >= self.max_container_size:
            self._flush()


class BlockCanutilsWriter(can.CanutilsLogWriter):
    """candump ``.log`` writer with a vectorised :meth:`write_block` (same text as python-can)."""

    def write_block(self, block: FrameBlock) -> None:
        n = len(block)
        if n == 0:
            return
        if self.last_timestamp is None:
            self.last_timestamp = float(block.timestamps[0])
        ts = np.maximum(block.timestamps, self.last_timestamp).tolist()
        channel = self.channel
        if isinstance(channel, int) or (isinstance(channel, str) and channel.isdigit()):
            channel = f"can{channel}"
        hexdata = block.data.tobytes().hex().upper()
        lines = [f"({t:f}) {channel} {i:03X}#{hexdata[16 * k:16 * k + 16]} R\n"
                 for k, (t, i) in enumerate(zip(ts, block.ids.tolist()))]
        self.file.write("".join(lines))


class MessageWriter:
    """Any ``can.Logger`` format, one message at a time."""

    def __init__(self, path: str | Path) -> None:
        self.logger = can.Logger(path)

    def write_block(self, block: FrameBlock) -> None:
        for message in block_messages(block):
            self.logger.on_message_received(message)

    def stop(self) -> None:
        self.logger.stop()


def block_messages(block: FrameBlock) -> list[can.Message]:
    """python-can messages of a block (11-bit IDs, DLC 8, timestamps of the block)."""
    raw = block.data.tobytes()
    message = can.Message
    return [message(timestamp=t, arbitration_id=i, is_extended_id=False, dlc=8, data=raw[8 * k:8 * k + 8],
                    check=False)
            for k, (i, t) in enumerate(zip(block.ids.tolist(), block.timestamps.tolist()))]


def open_block_writer(path: str | Path, **kwargs: Any) -> BlockWriter:
    """Writer for ``path`` by suffix; raises ``LinkError`` naming the path and the reason."""
    name = str(path).lower()
    if not is_log_file(path):
        raise LinkError(f"{path}: not a CAN log file; use .blf, .log or .asc")
    try:
        if name.endswith(".blf"):
            kwargs.setdefault("compression_level", BLF_COMPRESSION_LEVEL)
            return BlockBLFWriter(path, **kwargs)
        if name.endswith(".log"):
            return BlockCanutilsWriter(path, **kwargs)
        return MessageWriter(path)
    except OSError as exc:
        raise LinkError(f"{path}: cannot write log ({exc.strerror or exc})") from exc
