"""Block writers for python-can log files: whole frame blocks at once, same bytes as python-can.

Writing one ``can.Message`` at a time costs ≈ 2 µs to create the message plus ≈ 3 µs in
``BLFWriter.on_message_received`` (≈ 1.7 µs for the candump writer) — more than the whole
simulation of a frame, and too slow for the ≥ 50× real-time goal (6 joints at 500 Hz ≈ 3,350
frames per simulated second). So:

* ``.blf``: :class:`BlockBLFWriter` subclasses python-can's ``BLFWriter`` and packs a block of
  CAN_MESSAGE objects with one numpy structured array into the writer's container buffer; the
  writer's own container flushing, compression and header are reused. python-can has no public
  API for adding objects in bulk, and its public per-message path (``can.Message`` +
  ``on_message_received``) measured 12× slower here (231 k against 2.85 M frames/s), so the
  block path uses ``BLFWriter``'s private ``_buffer``/``_buffer_size``/``_flush`` (python-can
  4.x). That use is confined to :meth:`BlockBLFWriter._append_objects`; if a python-can release
  changes those internals, the writer logs a warning and falls back to the public per-message
  path (same bytes, slower). tests/test_sim_frames.py checks the file is byte-identical to
  per-message writing; tests/test_protocol_log_writers.py checks the fallback.
* ``.log`` (candump): :class:`BlockCanutilsWriter` formats all lines of a block in one join,
  exactly as ``CanutilsLogWriter`` does.
* ``.asc`` (Vector ASCII): :class:`BlockASCWriter` formats all lines of a block in one join, exactly as
  ``ASCWriter`` does (tests/test_sim_frames.py compares the text, python-can's ``LogReader`` reads it).
* anything else ``can.Logger`` supports (``.csv``, ``.trc``, …): per message.
"""

from __future__ import annotations

import logging
from pathlib import Path
from typing import Any, Protocol

import can
import numpy as np
from can.io import blf
from can.util import channel2int

from protocol.links import LinkError, LinkUsageError, is_log_file
from sim_controller.faults import FrameBlock

#: zlib level of BLF containers: 1 (fastest) — level 6 (python-can's default) made compression
#: 60 % of the recording time for ≈ 15 % smaller files.
BLF_COMPRESSION_LEVEL = 1

log = logging.getLogger(__name__)

#: One BLF CAN_MESSAGE object (OBJ_HEADER_BASE + OBJ_HEADER_V1 + CAN_MSG), as the BLF format defines it.
_CAN_OBJECT = np.dtype([
    ("signature", "S4"), ("header_size", "<u2"), ("header_version", "<u2"), ("object_size", "<u4"),
    ("object_type", "<u4"),                                                     # OBJ_HEADER_BASE
    ("flags", "<u4"), ("client_index", "<u2"), ("object_version", "<u2"), ("timestamp", "<u8"),  # V1
    ("channel", "<u2"), ("msg_flags", "u1"), ("dlc", "u1"), ("arbitration_id", "<u4"), ("data", "u1", (8,)),
])
_HEADER_SIZE = 16 + 16
_CAN_MESSAGE = 1          # BLF object type CAN_MESSAGE
_TIME_ONE_NANS = 2        # object timestamps in ns


def _python_can_layout_matches() -> bool:
    """True if python-can's BLF module still describes the object layout packed here."""
    try:
        return (blf.OBJ_HEADER_BASE_STRUCT.size + blf.OBJ_HEADER_V1_STRUCT.size == _HEADER_SIZE
                and _CAN_OBJECT.itemsize == _HEADER_SIZE + blf.CAN_MSG_STRUCT.size
                and (blf.CAN_MESSAGE, blf.TIME_ONE_NANS) == (_CAN_MESSAGE, _TIME_ONE_NANS))
    except AttributeError:
        return False


def _has_container_buffer(writer: blf.BLFWriter) -> bool:
    """True if ``writer`` has the private container buffer :meth:`BlockBLFWriter._append_objects` uses."""
    return (_python_can_layout_matches() and isinstance(getattr(writer, "_buffer", None), list)
            and isinstance(getattr(writer, "_buffer_size", None), int)
            and callable(getattr(writer, "_flush", None))
            and isinstance(getattr(writer, "max_container_size", None), int))


class BlockWriter(Protocol):
    def write_block(self, block: FrameBlock) -> None: ...
    def stop(self) -> None: ...


class BlockBLFWriter(blf.BLFWriter):
    """``BLFWriter`` with a vectorised :meth:`write_block` (received 11-bit data frames, DLC 8)."""

    def __init__(self, *args: Any, **kwargs: Any) -> None:
        super().__init__(*args, **kwargs)
        self.block_path = _has_container_buffer(self)
        if not self.block_path:
            log.warning("python-can %s: BLFWriter internals differ from 4.6; writing .blf one message at "
                        "a time (same file, slower)", can.__version__)

    def write_block(self, block: FrameBlock) -> None:
        n = len(block)
        if n == 0:
            return
        if not self.block_path:
            for message in block_messages(block):
                self.on_message_received(message)
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
        objects["object_type"] = _CAN_MESSAGE
        objects["flags"] = _TIME_ONE_NANS
        objects["timestamp"] = np.maximum(rel, 0)
        objects["channel"] = self.channel
        objects["dlc"] = 8 if block.dlc is None else block.dlc
        objects["arbitration_id"] = block.ids
        objects["data"] = block.data
        self._append_objects(objects.tobytes(), n)
        self.stop_timestamp = float(ts[-1])

    def _append_objects(self, packed: bytes, count: int) -> None:
        """The only use of python-can's private container buffer (see the module docstring):
        append ``count`` packed objects and let ``BLFWriter`` compress full containers."""
        self._buffer.append(packed)
        self._buffer_size += len(packed)
        self.object_count += count
        while self._buffer_size >= self.max_container_size:
            self._flush()


class BlockCanutilsWriter(can.CanutilsLogWriter):
    """candump ``.log`` writer with a vectorised :meth:`write_block` (same text as python-can)."""

    def write_block(self, block: FrameBlock) -> None:
        n = len(block)
        if n == 0:
            return
        if block.dlc is not None:            # frames shorter than 8 bytes: python-can's own formatting
            for message in block_messages(block):
                self.on_message_received(message)
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


class BlockASCWriter(can.ASCWriter):
    """Vector ``.asc`` writer with a vectorised :meth:`write_block` (same text as python-can's
    ``ASCWriter`` for received 11-bit data frames, DLC 8). The first frame goes through python-can's
    own path (it writes the ``Begin Triggerblock`` header with the start time); the rest of every block
    is formatted in one pass: relative time stamps computed as ``ASCWriter.log_event`` does, the hex
    data of the whole block in one ``bytes.hex`` call, one f-string per line, one ``write``."""

    def write_block(self, block: FrameBlock) -> None:
        n = len(block)
        if n == 0:
            return
        if block.dlc is not None:            # frames shorter than 8 bytes: python-can's own formatting
            for message in block_messages(block):
                self.on_message_received(message)
            return
        start = 0
        if not self.header_written:
            self.on_message_received(block_messages(block.take(np.arange(1)))[0])
            start = 1
            if n == 1:
                return
        ts = block.timestamps[start:]
        rel = np.where(ts >= self.started, ts - self.started, ts)
        channel = channel2int(None) or self.channel         # block messages carry no channel
        self.file.write(asc_lines(rel, block.ids[start:], block.data[start:], channel))


_HEX = np.frombuffer(b"".join(f"{b:02X}".encode() for b in range(256)), dtype=np.uint8).reshape(256, 2)
_STD_IDS = np.frombuffer(b"".join(f"{i:<15X}".encode() for i in range(0x800)), dtype=np.uint8).reshape(0x800, 15)
_HEX_T = np.ascontiguousarray(_HEX.T)
_STD_IDS_T = np.ascontiguousarray(_STD_IDS.T)


def asc_lines(rel: np.ndarray, ids: np.ndarray, data: np.ndarray, channel: int) -> str:
    """The ``ASCWriter`` lines of received 11-bit data frames (DLC 8) at relative times ``rel`` [s]:
    ``f"{t: 9.6f} {channel}  {id:<15X} Rx   d 8 {data hex, spaced}"``, built as one byte matrix.

    ``t`` is printed with 6 decimals as Python rounds it (the exact binary value, half to even): the
    microseconds are ``rint(t × 1e6)`` except where that product lies within 1e-4 of a half, which are
    formatted by Python; times of 1e9 s or more, negative times and ids ≥ 0x800 take Python's path."""
    n = len(rel)
    if n == 0:
        return ""
    if ids.min() < 0 or ids.max() >= 0x800 or rel.min() < 0 or rel.max() >= 1e9:
        return _asc_lines_python(rel, ids, data, channel)
    scaled = rel * 1e6
    micro = np.rint(scaled).astype(np.int64)
    near_half = np.abs(np.abs(scaled - np.floor(scaled)) - 0.5) < 1e-4
    for k in np.flatnonzero(near_half).tolist():
        whole, frac = f"{rel[k]:.6f}".split(".")
        micro[k] = int(whole) * 1_000_000 + int(frac)
    seconds, fraction = np.divmod(micro, 1_000_000)
    digits = np.maximum(1, np.floor(np.log10(np.maximum(seconds, 1))).astype(np.int64) + 1)
    digits[seconds >= 10 ** digits] += 1                 # log10 rounding at powers of ten
    widest = int(digits.max())
    tail = f" {channel}  ".encode(), b" Rx   d 8 "
    width = 1 + widest + 1 + 6 + len(tail[0]) + 15 + len(tail[1]) + 23 + 1
    t = np.full((width, n), ord(" "), dtype=np.uint8)   # one row per column of text: contiguous writes
    col = 1 + widest                                     # the decimal point (rows with fewer digits start later)
    rest = seconds.copy()
    for d in range(widest):                              # integer digits, right to left
        put = d < digits
        t[col - 1 - d] = np.where(put, rest % 10 + ord("0"), ord(" "))
        rest //= 10
    t[col] = ord(".")
    rest = fraction.copy()
    for d in range(6, 0, -1):
        t[col + d] = rest % 10 + ord("0")
        rest //= 10
    at = col + 7
    t[at:at + len(tail[0])] = np.frombuffer(tail[0], dtype=np.uint8)[:, None]
    at += len(tail[0])
    t[at:at + 15] = _STD_IDS_T[:, ids]
    at += 15
    t[at:at + len(tail[1])] = np.frombuffer(tail[1], dtype=np.uint8)[:, None]
    at += len(tail[1])
    for b in range(8):
        t[at + 3 * b:at + 3 * b + 2] = _HEX_T[:, data[:, b]]
    t[-1] = ord("\n")
    m = np.ascontiguousarray(t.T)
    if widest == 1:
        return m.tobytes().decode("ascii")
    keep = np.ones((n, width), dtype=bool)
    keep[:, :widest] = np.arange(widest)[None, :] >= (widest - digits)[:, None]   # cut the unused leading columns
    return m[keep].tobytes().decode("ascii")


def _asc_lines_python(rel: np.ndarray, ids: np.ndarray, data: np.ndarray, channel: int) -> str:
    hexdata = data.tobytes().hex(" ").upper()
    return "".join([f"{t: 9.6f} {channel}  {i:<15X} Rx   d 8 {hexdata[24 * k:24 * k + 23]}\n"
                    for k, (t, i) in enumerate(zip(rel.tolist(), ids.tolist()))])


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
    """python-can messages of a block (11-bit IDs, DLC 8 or the block's, timestamps of the block)."""
    raw = block.data.tobytes()
    message = can.Message
    if block.dlc is not None:
        return [message(timestamp=t, arbitration_id=i, is_extended_id=False, dlc=n, data=raw[8 * k:8 * k + n],
                        check=False)
                for k, (i, t, n) in enumerate(zip(block.ids.tolist(), block.timestamps.tolist(), block.dlc.tolist()))]
    return [message(timestamp=t, arbitration_id=i, is_extended_id=False, dlc=8, data=raw[8 * k:8 * k + 8],
                    check=False)
            for k, (i, t) in enumerate(zip(block.ids.tolist(), block.timestamps.tolist()))]


def open_block_writer(path: str | Path, **kwargs: Any) -> BlockWriter:
    """Writer for ``path`` by suffix; raises ``LinkError`` naming the path and the reason."""
    name = str(path).lower()
    if not is_log_file(path):
        raise LinkUsageError(f"{path}: not a CAN log file; use .blf, .log or .asc")
    try:
        if name.endswith(".blf"):
            kwargs.setdefault("compression_level", BLF_COMPRESSION_LEVEL)
            return BlockBLFWriter(path, **kwargs)
        if name.endswith(".log"):
            return BlockCanutilsWriter(path, **kwargs)
        if name.endswith(".asc"):
            return BlockASCWriter(path, **kwargs)
        return MessageWriter(path)
    except OSError as exc:
        raise LinkError(f"{path}: cannot write log ({exc.strerror or exc})") from exc
