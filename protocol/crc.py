"""CRC-8H2F (AUTOSAR): polynomial 0x2F, initial value 0xFF, final XOR 0xFF, not reflected.

Check value: ``crc8h2f(b"123456789") == 0xDF``.  Chaining follows the AUTOSAR convention: the
result of one call XOR 0xFF is the ``init`` of the next call over the following bytes.

The scalar path is ``crccheck``'s ``Crc8Autosar`` (the same algorithm, maintained elsewhere).
The block path (:func:`crc8h2f_block`, one CRC per row of a uint8 array) stays table-driven in
numpy: measured 13 ns per 7-byte row on blocks of ≥ 10,000 rows against 3.7 µs per call for
``Crc8Autosar`` (``python -m protocol.bench_micro``); its 256-entry table is derived from ``Crc8Autosar``.
"""

from __future__ import annotations

import numpy as np
from crccheck.crc import Crc8Autosar

POLYNOMIAL = 0x2F
INITIAL_VALUE = 0xFF
FINAL_XOR = 0xFF
CHECK_VALUE = 0xDF  # CRC of ASCII "123456789"


def crc8h2f(data: bytes | bytearray | memoryview, init: int = INITIAL_VALUE) -> int:
    """CRC-8H2F of ``data`` starting from register ``init`` (crccheck ``Crc8Autosar``)."""
    return Crc8Autosar.calc(data, init & 0xFF)


def _build_table() -> np.ndarray:
    # Register after feeding byte i into register 0: the final XOR of calc() undone.
    return np.array([Crc8Autosar.calc(bytes((index,)), 0) ^ FINAL_XOR for index in range(256)], dtype=np.uint8)


CRC8H2F_TABLE: np.ndarray = _build_table()
"""256-entry table: ``TABLE[r ^ byte]`` is the register after feeding ``byte`` into register ``r``."""


def crc8h2f_block(rows: np.ndarray, init: int | np.ndarray = INITIAL_VALUE) -> np.ndarray:
    """CRC-8H2F of every row of ``rows`` (uint8[n, k]) -> uint8[n].

    ``init`` is a scalar or a per-row uint8[n] array of starting registers (e.g. the register
    after the frame's data ID).  One table lookup per column over the whole block.
    """
    block = np.asarray(rows, dtype=np.uint8)
    if block.ndim != 2:
        raise ValueError(f"rows: expected a 2-D uint8 array [n, k], got shape {block.shape}")
    register = np.empty(block.shape[0], dtype=np.uint8)
    register[...] = np.asarray(init, dtype=np.int64) & 0xFF
    for column in range(block.shape[1]):
        register = CRC8H2F_TABLE[register ^ block[:, column]]
    return register ^ np.uint8(FINAL_XOR)
