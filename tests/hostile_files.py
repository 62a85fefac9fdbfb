"""Builders of hostile inputs (the files and streams a hostile user or a bad day produces) and a way to
run a command as a user would while measuring it: exit code, output, peak memory, under limits.

Used by the tests of issue 28 and by ``tests/corpus/make_corpus.py``, which writes the small ones
into the committed adversarial corpus (``tests/corpus/``).
"""

from __future__ import annotations

import os
import random
import resource
import signal
import struct
import subprocess
import sys
import threading
import zlib
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from protocol.frame_blocks import decode_block, encode_controller_status_block

BLF_HEADER = struct.Struct("<4sHHLL")          # signature, header size, header version, object size, type
BLF_CONTAINER = struct.Struct("<H6xL4x")        # compression method, uncompressed size
LOG_CONTAINER, ZLIB_DEFLATE = 10, 2


# -- BLF --------------------------------------------------------------------------------------------
def blf_objects(raw: bytes) -> list[tuple[int, int, int]]:
    """(offset, size, type) of the top-level objects of a BLF file (after its file header)."""
    header_size = struct.unpack_from("<4sL", raw, 0)[1]
    out, pos = [], header_size
    while pos + BLF_HEADER.size <= len(raw):
        _, _, _, size, kind = BLF_HEADER.unpack_from(raw, pos)
        out.append((pos, size, kind))
        pos += size + size % 4
    return out


def zlib_bomb(inflated_bytes: int) -> bytes:
    """A valid zlib stream of ``inflated_bytes`` zero bytes (a multiple of 1 MiB), ≈ 1/1000 of that
    compressed: one MiB deflated once and its (byte-aligned, full-flushed) blocks repeated, then a final
    empty block and the Adler-32 of the whole; built in milliseconds, whatever the size."""
    chunk = bytes(1 << 20)
    deflate = zlib.compressobj(9)
    first = deflate.compress(chunk) + deflate.flush(zlib.Z_FULL_FLUSH)       # with the 2-byte header
    repeat = deflate.compress(chunk) + deflate.flush(zlib.Z_FULL_FLUSH)
    size = (inflated_bytes >> 20) << 20
    checksum = (size % 65521) << 16 | 1           # Adler-32 of zeros: A stays 1, B counts the bytes
    return first + repeat * ((inflated_bytes >> 20) - 1) + b"\x03\x00" + checksum.to_bytes(4, "big")


def container(payload: bytes, claimed: int, method: int = ZLIB_DEFLATE) -> bytes:
    """A LOG_CONTAINER object holding ``payload`` (its header claiming ``claimed`` inflated bytes)."""
    size = BLF_HEADER.size + BLF_CONTAINER.size + len(payload)
    body = BLF_HEADER.pack(b"LOBJ", BLF_HEADER.size, 1, size, LOG_CONTAINER) + BLF_CONTAINER.pack(method, claimed)
    return body + payload + bytes(size % 4)


def with_object_before(raw: bytes, index: int, obj: bytes) -> bytes:
    """``raw`` with ``obj`` inserted before its ``index``-th top-level object."""
    offset = blf_objects(raw)[index][0]
    return raw[:offset] + obj + raw[offset:]


def with_object_size(raw: bytes, index: int, size: int) -> bytes:
    """``raw`` with the size field of its ``index``-th top-level object set to ``size``."""
    offset = blf_objects(raw)[index][0]
    return raw[:offset + 8] + struct.pack("<L", size) + raw[offset + 12:]


# -- text logs ------------------------------------------------------------------------------------
def frame_line_indices(lines: list[bytes], suffix: str) -> list[int]:
    """Indices of the lines that hold one frame each (candump ``(t) can0 ID#DATA``, ASC ``t 1 ID Rx d …``)."""
    if suffix == "log":
        return [i for i, line in enumerate(lines) if line.startswith(b"(")]
    return [i for i, line in enumerate(lines) if b" Rx " in line or b" Tx " in line]


def with_bad_byte(raw: bytes, suffix: str, which: float = 0.5, byte: bytes = b"\xff") -> bytes:
    """A text log with one byte of one frame line (at fraction ``which`` of them) replaced by ``byte``."""
    lines = raw.splitlines(keepends=True)
    i = frame_line_indices(lines, suffix)[int(len(frame_line_indices(lines, suffix)) * which)]
    lines[i] = lines[i][:10] + byte + lines[i][11:]
    return b"".join(lines)


def with_garbage_lines(raw: bytes, count: int, seed: int = 0) -> tuple[bytes, int]:
    """A text log with ``count`` lines of random bytes (no line end inside) inserted at random places
    after the header; returns it and the number of lines inserted."""
    rng = random.Random(seed)
    lines = raw.splitlines(keepends=True)
    for _ in range(count):
        garbage = bytes(rng.choice([b for b in range(256) if b not in (10, 13)]) for _ in range(rng.randrange(1, 80)))
        lines.insert(rng.randrange(6, len(lines) - 1), garbage + b"\n")
    return b"".join(lines), count


# -- frame streams --------------------------------------------------------------------------------
Frames = tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]


def shuffled(frames: Frames, seed: int = 0) -> Frames:
    """The frames in random order (time stamps left in place, as a shuffled log replays them)."""
    ids, data, dlc, ts = frames
    order = np.random.default_rng(seed).permutation(len(ids))
    return ids[order], data[order], dlc[order], ts


def status_rewritten(frames: Frames, *, cycle=None, tick=None) -> Frames:
    """The frames with every ControllerStatus re-encoded (valid CRC, same alive counter): its cycle
    number and/or tick replaced by ``cycle(k, old)`` / ``tick(k, old)`` of the k-th status frame."""
    ids, data, dlc, ts = frames
    rows = np.flatnonzero(ids == 0x080)
    dec = decode_block(ids[rows], data[rows], dlc[rows])
    k = np.arange(rows.size)
    new_cycle = dec.cycle if cycle is None else np.asarray(cycle(k, dec.cycle)) % (1 << 16)
    new_tick = dec.status_tick if tick is None else np.asarray(tick(k, dec.status_tick)) % (1 << 24)
    data = data.copy()
    data[rows] = encode_controller_status_block(dec.counter, dec.mode, new_cycle, dec.segment, new_tick)
    return ids, data, dlc, ts


# -- configs and states ---------------------------------------------------------------------------
def deep_toml(depth: int, kind: str = "array") -> str:
    """A TOML document nested ``depth`` deep: arrays ``a = [[[…]]]`` or inline tables ``a = {b = {…}}``."""
    if kind == "array":
        return "a = " + "[" * depth + "]" * depth + "\n"
    return "a = " + "{b = " * depth + "1" + "}" * depth + "\n"


def state_with_long_integer(digits: int = 5000, robot: str = "robot1") -> str:
    """A version-1 state file whose ``last_emitted`` holds an integer of ``digits`` digits."""
    return '{"version": 1, "robot": "%s", "last_emitted": {"0": %s}, "ingest": {}, "joints": {}}' % (
        robot, "9" * digits)


# -- running a command as a user does ---------------------------------------------------------------
@dataclass
class Run:
    returncode: int
    stdout: str
    stderr: str
    max_rss_mb: float
    timed_out: bool


def run_measured(args: list[str], *, timeout: float = 300.0, file_size_limit: int | None = None,
                 cwd: str | Path | None = None, env: dict[str, str] | None = None,
                 memory_limit: int | None = None) -> Run:
    """Run ``args`` to its end (its process group killed after ``timeout`` s); its peak resident set
    from ``wait4``. ``file_size_limit``: RLIMIT_FSIZE in bytes (a write past it fails with EFBIG, as on
    a full disk; standard output and error are pipes, which it does not limit). ``memory_limit``:
    RLIMIT_AS in bytes (an allocation past it fails: MemoryError, std::bad_alloc)."""

    def limits() -> None:
        if memory_limit is not None:
            resource.setrlimit(resource.RLIMIT_AS, (memory_limit, memory_limit))
        if file_size_limit is not None:
            signal.signal(signal.SIGXFSZ, signal.SIG_IGN)         # EFBIG instead of a signal
            resource.setrlimit(resource.RLIMIT_FSIZE, (file_size_limit, file_size_limit))

    proc = subprocess.Popen(args, stdout=subprocess.PIPE, stderr=subprocess.PIPE, cwd=cwd, preexec_fn=limits,
                            env={**os.environ, "PYTHONDONTWRITEBYTECODE": "1", **(env or {})},
                            start_new_session=True)
    output: dict[str, bytes] = {}
    readers = [threading.Thread(target=lambda name=name, pipe=pipe: output.__setitem__(name, pipe.read()))
               for name, pipe in (("out", proc.stdout), ("err", proc.stderr))]
    for reader in readers:
        reader.start()
    fired = threading.Event()

    def kill() -> None:
        fired.set()
        os.killpg(proc.pid, signal.SIGKILL)

    timer = threading.Timer(timeout, kill)
    timer.start()
    try:
        _, status, usage = os.wait4(proc.pid, 0)
    finally:
        timer.cancel()
    proc.returncode = os.waitstatus_to_exitcode(status)
    for reader in readers:
        reader.join()
    return Run(proc.returncode, output["out"].decode(errors="replace"), output["err"].decode(errors="replace"),
               usage.ru_maxrss / 1024.0, fired.is_set())


def edge_monitor(*args: str) -> list[str]:
    """The ``edge-monitor`` command line of this interpreter."""
    return [sys.executable, "-m", "edge_monitor.cli", *args]
