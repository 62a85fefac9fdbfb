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
python-can's own parser (``BLFReader._parse_data``) from that object on, so the frames and their order
are python-can's. The container walk is python-can's ``__iter__`` made robust (file hostile, memory
bounded): a damaged container is skipped and counted and the next one read, a container never
inflates past :data:`MAX_CONTAINER_BYTES`, and an object size the file cannot hold ends the walk as
truncation (:class:`BLFDamage`) instead of swallowing the rest of the file. Used only while
python-can has the private parts used here (:func:`supported`); otherwise
:mod:`edge_monitor.sources.log_source` iterates ``LogReader``.
"""

from __future__ import annotations

import gzip
import math
import os
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


class BLFDamage(ValueError):
    """The container walk cannot go on: a damaged object header (bad signature or an object size the
    file cannot hold). What came before it was read; the rest of the file is lost (truncation)."""


#: Largest inflated container accepted [bytes]; loggers write ≈ 128 KiB. A larger one (a zlib bomb:
#: 2 MB of file inflating to GiB) is skipped and counted, never inflated past this.
MAX_CONTAINER_BYTES = 16 << 20
#: Largest object read into memory [bytes]; a larger one is skipped unread (seek) and counted.
MAX_OBJECT_BYTES = 64 << 20

#: ``on_skip(reason, frames)``: a container or object skipped, with an estimate of the frames it held.
SkipCallback = Callable[[str, int], None]


def _estimated_frames(inflated_bytes: int) -> int:
    """Frames a container of ``inflated_bytes`` held, estimated at one fixed-layout CAN object each 48 bytes."""
    return max(int(inflated_bytes) // _SIZE, 1)


def _inflate(method: int, payload: bytes, claimed: int) -> tuple[bytes | None, str | None]:
    """A container's data, or (None, why it is skipped): unknown method, damaged zlib stream, or a
    stream that inflates past :data:`MAX_CONTAINER_BYTES`."""
    if method == blf.NO_COMPRESSION:
        return payload, None
    if method != blf.ZLIB_DEFLATE:
        return None, f"unknown compression method {method}"
    inflater = zlib.decompressobj()
    try:
        data = inflater.decompress(payload, MAX_CONTAINER_BYTES)
    except zlib.error as exc:
        return None, f"damaged zlib data ({exc})"
    if inflater.unconsumed_tail:
        return None, (f"inflates past {MAX_CONTAINER_BYTES} bytes (its header says {claimed}): "
                      "not inflated further")
    return data, None


def _sane_length(data: bytes, start: int) -> int | None:
    """Where, walking the objects from ``start`` as python-can does, an object says it is smaller than
    an object header (bytes from ``start``), or None. python-can's parser loops forever on such an
    object (its next position is its own)."""
    header = blf.OBJ_HEADER_BASE_STRUCT
    pos = start
    while pos + header.size <= len(data):
        found = data.find(b"LOBJ", pos, pos + 8)
        if found < 0:
            return None
        size = header.unpack_from(data, found)[3]
        if size < header.size:
            return found - start
        pos = found + size
    return None


def _read_objects(reader: Any, data: bytes, at: int, start: float, resync: bool, pending: list[Arrays],
                  add_messages: Callable[[list[can.Message]], None], skip: SkipCallback) -> tuple[bytes, bool]:
    """The objects of one container's ``data`` (the previous container's tail first) into ``pending``:
    fixed-layout runs with numpy, the rest python-can's way. A damaged object is skipped (counted) and
    reading resumes at the next object signature; after a skipped container (``resync``) it begins
    there too. Returns the unparsed tail (an object the container cut) and whether to resync next."""
    pos = 0
    if resync:
        pos = data.find(b"LOBJ")
        if pos < 0:
            return b"", True
    while pos < len(data):
        run = _object_run(data, pos)
        if run:
            pending.append(objects_to_arrays(data, pos, run, start))
            pos += run * _SIZE
            continue
        sane = _sane_length(data, pos)
        try:      # another object type, padding, damage, an object cut by the container: python-can's way
            if sane is None:
                return _parse_rest(reader, data[pos:], add_messages), False
            _parse_rest(reader, data[pos:pos + sane], add_messages)
            reader._pos = sane
            raise blf.BLFParseError(f"object size below {blf.OBJ_HEADER_BASE_STRUCT.size} bytes")
        except Exception as exc:          # a damaged object: what came before it is kept; on at the next one
            failed_at = pos + int(reader._pos)
            skip(f"container at byte {at}: unreadable object at offset {failed_at} ({exc or type(exc).__name__})", 1)
            pos = data.find(b"LOBJ", failed_at + 1)
            if pos < 0:
                return b"", True
    return b"", False


def stream_size(file: Any) -> float:
    """Bytes a BLF stream holds: the file's size on disk; unknown (infinite) for a gzip-compressed one, whose
    size on disk is not what it unpacks to (a ``.blf.gz`` ends where its stream ends)."""
    if isinstance(file, gzip.GzipFile):
        return math.inf
    return os.fstat(file.fileno()).st_size


def container_arrays(reader: Any, on_skip: SkipCallback | None = None) -> Iterator[Arrays]:
    """Frame arrays of a BLF file, in file order, one or more per container (python-can's container
    walk; its parser for whatever is not a fixed-layout CAN_MESSAGE).

    Damage inside a container (undecodable zlib data, a container inflating past
    :data:`MAX_CONTAINER_BYTES`) skips that container, a damaged object inside one skips that object:
    ``on_skip`` is told, and reading goes on at the next object signature. Damage to the walk itself (an
    object header without its signature, an object size smaller than a header) raises
    :class:`BLFDamage` after the frames before it; an object larger than what is left of the file
    (a file cut short, or a damaged size) is read as far as the file goes, then the same. The caller closes
    the reader (``with reader:``): the position its file ends at tells a compressed stream's length."""
    base_size = blf.OBJ_HEADER_BASE_STRUCT.size
    unpack_base = blf.OBJ_HEADER_BASE_STRUCT.unpack
    unpack_container = blf.LOG_CONTAINER_STRUCT.unpack_from
    container_size = blf.LOG_CONTAINER_STRUCT.size
    start = float(reader.start_timestamp)
    pending: list[Arrays] = []
    skip = on_skip or (lambda reason, frames: None)

    def add_messages(messages: list[can.Message]) -> None:
        if messages:
            pending.append(messages_to_arrays(messages))

    tail, resync = b"", False       # resync: a container was skipped, the next one may begin mid-object
    file = reader.file
    file_size = stream_size(file)
    while True:
        at = file.tell()
        header = file.read(base_size)
        if not header:
            break
        if len(header) < base_size:
            raise BLFDamage(f"object header at byte {at} cut short ({len(header)} of {base_size} bytes)")
        signature, _, _, obj_size, obj_type = unpack_base(header)
        if signature != b"LOBJ":
            raise BLFDamage(f"no object signature at byte {at}")
        if obj_size < base_size:
            raise BLFDamage(f"object at byte {at} says it has {obj_size} bytes, less than its header")
        left = file_size - at
        cut = None      # an object the file cannot hold: read what is there (a file cut short), then stop
        if obj_size > left:
            cut = f"object at byte {at} says it has {obj_size} bytes; {left} are left"
            obj_size = left
        body = obj_size - base_size
        if body > MAX_OBJECT_BYTES:
            file.seek(body + obj_size % 4, os.SEEK_CUR)
            if obj_type == blf.LOG_CONTAINER:
                skip(f"container at byte {at}: {obj_size} bytes, more than {MAX_OBJECT_BYTES}: skipped unread",
                     _estimated_frames(body))
                tail, resync = b"", True
            if cut:
                raise BLFDamage(cut)
            continue
        obj_data = file.read(body)
        file.read(obj_size % 4)
        if obj_type != blf.LOG_CONTAINER or len(obj_data) < container_size:
            if cut:
                raise BLFDamage(cut)
            continue
        method, claimed = unpack_container(obj_data)
        chunk, why = _inflate(method, obj_data[container_size:], claimed)
        if chunk is None:
            skip(f"container at byte {at}: {why}", _estimated_frames(min(claimed, MAX_CONTAINER_BYTES)))
            tail, resync = b"", True
            if cut:
                raise BLFDamage(cut)
            continue
        data = tail + chunk if tail else chunk
        tail, resync = _read_objects(reader, data, at, start, resync, pending, add_messages, skip)
        yield from pending
        pending.clear()
        if cut:
            raise BLFDamage(cut)
