"""Micro-benchmarks of the protocol layer: CRC paths and slcan line splitting.

Run: ``nice python -m protocol.bench_micro`` (a few seconds). Prints one line per figure; the
hand-written implementations that were replaced are reproduced here only for comparison.
"""

from __future__ import annotations

import logging
import re
import timeit

import numpy as np
from crccheck.crc import Crc8Autosar

from protocol.crc import CRC8H2F_TABLE, crc8h2f_block
from protocol.slcan_fast import SlcanLineSplitter

_TABLE = [int(v) for v in CRC8H2F_TABLE]


def _table_scalar(data: bytes, init: int) -> int:
    """The former hand-written scalar CRC-8H2F (table-driven), for comparison."""
    register = init
    for byte in data:
        register = _TABLE[register ^ byte]
    return register ^ 0xFF


_OLD_LINE = re.compile(rb"[^\r\a]*[\r\a]")


def _old_split(buf: bytearray, chunk: bytes) -> None:
    """The former regex splitter (quadratic on unterminated input), for comparison."""
    buf += chunk
    end = 0
    for match in _OLD_LINE.finditer(buf):
        end = match.end()
    del buf[:end]
    if len(buf) > 4096:
        buf.clear()


def _best(statement, number: int, repeat: int = 5) -> float:
    return min(timeit.repeat(statement, number=number, repeat=repeat)) / number


def bench_crc() -> None:
    data, n = bytes(range(1, 8)), 20_000
    print(f"CRC scalar, 7 bytes: crccheck Crc8Autosar {_best(lambda: Crc8Autosar.calc(data, 0x3C), n) * 1e6:.2f} µs, "
          f"former table loop {_best(lambda: _table_scalar(data, 0x3C), n) * 1e6:.2f} µs per call")
    rng = np.random.default_rng(0)
    for rows in (100, 10_000, 100_000):
        block = rng.integers(0, 256, (rows, 7), dtype=np.uint8)
        init = rng.integers(0, 256, rows, dtype=np.uint8)
        per_row = _best(lambda: crc8h2f_block(block, init), max(1, 200_000 // rows)) / rows
        print(f"CRC block (numpy), {rows} rows of 7 bytes: {per_row * 1e9:.1f} ns per row")


def bench_slcan_split() -> None:
    rng = np.random.default_rng(1)
    garbage = rng.integers(0, 256, 200_000, dtype=np.uint8)
    garbage = garbage[(garbage != 0x0D) & (garbage != 0x07)].tobytes()
    chunks = [garbage[i:i + 4096] for i in range(0, len(garbage), 4096)]

    def new() -> None:
        splitter = SlcanLineSplitter()
        for chunk in chunks:
            splitter.feed(chunk)

    def old() -> None:
        buf = bytearray()
        for chunk in chunks:
            _old_split(buf, chunk)

    t_new, t_old = _best(new, 5), _best(old, 1, repeat=1)
    print(f"slcan split, {len(garbage) / 1e3:.0f} KB without terminator in 4 KB chunks: "
          f"{len(garbage) / t_new / 1e6:.0f} MB/s (former regex: {len(garbage) / t_old / 1e3:.1f} KB/s, "
          f"{t_old:.1f} s)")
    line = b"t1008" + b"0123456789ABCDEF" + b"\r"
    stream = line * 20_000
    chunks = [stream[i:i + 4096] for i in range(0, len(stream), 4096)]

    def frames() -> None:
        splitter = SlcanLineSplitter()
        for chunk in chunks:
            splitter.feed(chunk)

    t = _best(frames, 3)
    print(f"slcan split, valid classical frames: {len(stream) / t / 1e6:.1f} MB/s = {20_000 / t:,.0f} lines/s")


if __name__ == "__main__":
    logging.disable(logging.WARNING)  # the splitter warns about the garbage it is fed here
    bench_crc()
    bench_slcan_split()
