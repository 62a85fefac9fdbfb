"""CRC-8H2F (AUTOSAR): polynomial 0x2F, initial value 0xFF, final XOR 0xFF, not reflected.

Check value: ``crc8h2f(b"123456789") == 0xDF``.  Chaining follows the AUTOSAR convention: the
result of one call XOR 0xFF is the ``init`` of the next call over the following bytes.
"""

from __future__ import annotations

import numpy as np

POLYNOMIAL = 0x2F
INITIAL_VALUE = 0xFF
FINAL_XOR = 0xFF
CHECK_VALUE = 0xDF  # CRC of ASCII "123456789"


def crc8h2f_bitwise(data: bytes, init: int = INITIAL_VALUE) -> int:
    """Reference implementation, one bit at a time (slow; used to verify the table)."""
    register = init & 0xFF
    for byte in data:
        register ^= byte
        for _ in range(8):
            if register & 0x80:
                register = ((register << 1) ^ POLYNOMIAL) & 0xFF
            else:
                register = (register << 1) & 0xFF
    return register ^ FINAL_XOR


def _build_table() -> np.ndarray:
    table = np.zeros(256, dtype=np.uint8)
    for index in range(256):
        register = index
        for _ in range(8):
            register = ((register << 1) ^ POLYNOMIAL) & 0xFF if register & 0x80 else (register << 1) & 0xFF
        table[index] = register
    return table


CRC8H2F_TABLE: np.ndarray = _build_table()
"""256-entry table: ``TABLE[r ^ byte]`` is the register after feeding ``byte`` into register ``r``."""
_TABLE_LIST: list[int] = [int(v) for v in CRC8H2F_TABLE]


def crc8h2f(data: bytes | bytearray | memoryview, init: int = INITIAL_VALUE) -> int:
    """CRC-8H2F of ``data`` starting from register ``init`` (scalar, table-driven)."""
    register = init & 0xFF
    table = _TABLE_LIST
    for byte in data:
        register = table[register ^ byte]
    return register ^ FINAL_XOR


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
