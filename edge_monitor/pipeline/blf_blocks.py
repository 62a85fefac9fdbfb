"""Vectorised reading of ``.blf`` logs: whole containers of CAN_MESSAGE objects into frame arrays.

python-can's ``BLFReader`` unpacks one object at a time and builds a ``can.Message`` for each frame
(≈ 1.5 µs per frame here), which made reading the file most of a replay's time (profile in
docs/benchmarks/agent.md). A BLF container written by a logger usually holds nothing but CAN_MESSAGE
objects of one fixed size (48 bytes, object header version 1), so after decompressing a container
this module checks every 48-byte stride at once with numpy and turns the run of such objects into the
arrays of :func:`protocol.frames.messages_to_arrays` directly — the same values, bit for bit:

* timestamps ``start + ticks × factor`` (python-can rounds ``Decimal(ticks) × 1e-9`` (or ``1e-5``) to a
  float, which is the correctly rounded quotient ``ticks / 1e9`` numpy computes for ticks < 2⁵³);
* ids with ``CAN_EFF_FLAG`` or'ed in for extended and remote frames;
* data zero-padded beyond the DLC, dlc = min(DLC, 8) (python-can keeps ``data[:dlc]``), 0 for a
  remote frame (whose ``Message`` has no data).

Anything else (other object types, a padding, another header version, a damaged object) is handed to
python-can's own parser (``BLFReader._parse_data``) from that object on, so the frames, their order
and the errors raised on damage are python-can's. The container walk is python-can's ``__iter__``
(same reads, same errors). Used only while python-can has the private parts used here
(:func:`supported`); otherwise :mod:`edge_monitor.pipeline.log_source` iterates ``LogReader``.
"""

from __future__ import annotations

import struct
import zlib
from typing import Any, Callable, Iterator

import can
import numpy as np
from can.io import blf

from protocol.frame_blocks import CAN_EFF_FLAG, FRAME_LENGTH, messages_to_arrays

#: One BLF CAN_MESSAGE object (OBJ_HEADER_BASE + OBJ_HEADER_V1 + CAN_MSG).
CAN_OBJECT = np.dtype([
    ("signature", "S4"), ("header_size", "<u2"), ("header_version", "<u2"), ("object_size", "<u4"),
    ("object_type", "<u4"),
    ("flags", "<u4"), ("client_index", "<u2"), ("object_version", "<u2"), ("timestamp", "<u8"),
    ("channel", "<u2"), ("msg_flags", "u1"), ("dlc", "u1"), ("arbitration_id", "<u4"), ("data", "u1", (8,)),
])
_SIZE = CAN_OBJECT.itemsize          # 48
TIME_TEN_MICS = 1                    # object flag: 10 µs ticks; any other flag: ns (as python-can)

Arrays = tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]


def supported(reader: Any) -> bool:
    """True if ``reader`` is python-can's BLFReader with the parts this module relies on."""
    try:
        return (isinstance(reader, blf.BLFReader) and callable(getattr(reader, "_parse_data", None))
                and hasattr(reader, "file") and isinstance(reader.start_timestamp, (int, float))
                and blf.OBJ_HEADER_BASE_STRUCT.size + blf.OBJ_HEADER_V1_STRUCT.size + blf.CAN_MSG_STRUCT.size == _SIZE
                and (blf.CAN_MESSAGE, blf.LOG_CONTAINER, blf.CAN_MSG_EXT, blf.REMOTE_FLAG)
                == (1, 10, 0x8000_0000, 0x80))
    except AttributeError:
        return False


def _object_run(data: bytes, pos: int) -> int:
    """How many CAN_MESSAGE objects of the fixed layout follow one another from ``pos``."""
    count = (len(data) - pos) // _SIZE
    if count == 0:
        return 0
    objects = np.frombuffer(data, dtype=CAN_OBJECT, count=count, offset=pos)
    ok = ((objects["signature"] == b"LOBJ") & (objects["header_size"] == 32) & (objects["header_version"] == 1)
          & (objects["object_size"] == _SIZE) & (objects["object_type"] == blf.CAN_MESSAGE))
    bad = np.flatnonzero(~ok)
    return int(bad[0]) if bad.size else count


def objects_to_arrays(data: bytes, pos: int, count: int, start_timestamp: float) -> Arrays:
    """Frame arrays of ``count`` fixed-layout CAN_MESSAGE objects at ``pos`` (as messages_to_arrays)."""
    objects = np.frombuffer(data, dtype=CAN_OBJECT, count=count, offset=pos)
    raw_id = objects["arbitration_id"].astype(np.int64)
    ids = raw_id & 0x1FFF_FFFF
    remote = (objects["msg_flags"] & blf.REMOTE_FLAG) != 0
    ids[((raw_id & blf.CAN_MSG_EXT) != 0) | remote] |= CAN_EFF_FLAG
    dlc = np.minimum(objects["dlc"], FRAME_LENGTH).astype(np.int64)
    dlc[remote] = 0                                   # a remote frame's Message has no data
    payload = objects["data"].copy()
    short = dlc < FRAME_LENGTH
    if short.any():
        payload[short] *= (np.arange(FRAME_LENGTH) < dlc[short, None]).astype(np.uint8)
    ticks_per_s = np.where(objects["flags"] == TIME_TEN_MICS, 1e5, 1e9)
    return ids, payload, dlc, objects["timestamp"].astype(np.float64) / ticks_per_s + start_timestamp


def _parse_rest(reader: Any, data: bytes, out: Callable[[list[can.Message]], None]) -> bytes:
    """python-can's ``_parse_container`` on ``data``: messages to ``out`` (also those before an error,
    which is then raised), the unparsed tail returned."""
    messages: list[can.Message] = []
    reader._pos = 0
    try:
        for message in reader._parse_data(data):
            messages.append(message)
    except struct.error:
        pass                                          # not enough data for a struct: rest in the next container
    except BaseException:
        out(messages)
        raise
    out(messages)
    return data[reader._pos:]


def container_arrays(reader: Any) -> Iterator[Arrays]:
    """Frame arrays of a BLF file, in file order, one or more per container (python-can's container
    walk; its parser for whatever is not a fixed-layout CAN_MESSAGE)."""
    base_size = blf.OBJ_HEADER_BASE_STRUCT.size
    unpack_base = blf.OBJ_HEADER_BASE_STRUCT.unpack
    unpack_container = blf.LOG_CONTAINER_STRUCT.unpack_from
    container_size = blf.LOG_CONTAINER_STRUCT.size
    start = float(reader.start_timestamp)
    pending: list[Arrays] = []

    def add_messages(messages: list[can.Message]) -> None:
        if messages:
            pending.append(messages_to_arrays(messages))

    tail = b""
    read = reader.file.read
    while True:
        header = read(base_size)
        if not header:
            break
        signature, _, _, obj_size, obj_type = unpack_base(header)
        if signature != b"LOBJ":
            raise blf.BLFParseError()
        obj_data = read(obj_size - base_size)
        read(obj_size % 4)
        if obj_type != blf.LOG_CONTAINER:
            continue
        method, _ = unpack_container(obj_data)
        payload = obj_data[container_size:]
        if method == blf.NO_COMPRESSION:
            chunk = payload
        elif method == blf.ZLIB_DEFLATE:
            chunk = zlib.decompressobj().decompress(payload)
        else:
            blf.LOG.warning("Unknown compression method (%d)", method)
            continue
        data = tail + chunk if tail else chunk
        pos = 0
        while True:
            run = _object_run(data, pos)
            if not run:
                break
            pending.append(objects_to_arrays(data, pos, run, start))
            pos += run * _SIZE
        error: BaseException | None = None
        try:      # the rest (another object type, padding, damage, an object cut by the container) python-can's way
            tail = _parse_rest(reader, data[pos:], add_messages) if pos < len(data) else b""
        except Exception as exc:     # damage: what came before it first, then python-can's error
            error = exc
        yield from pending
        pending.clear()
        if error is not None:
            raise error
    reader.stop()

