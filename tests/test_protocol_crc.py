"""CRC-8H2F: check value, AUTOSAR vectors, and both paths (scalar, numpy block) against crccheck."""

import numpy as np
from crccheck.crc import Crc8Autosar
from hypothesis import given, settings
from hypothesis import strategies as st

from protocol.crc import CHECK_VALUE, CRC8H2F_TABLE, FINAL_XOR, crc8h2f, crc8h2f_block


def test_check_value_of_autosar_crc8h2f():
    assert CHECK_VALUE == 0xDF
    assert crc8h2f(b"123456789") == 0xDF
    assert crc8h2f_block(np.frombuffer(b"123456789", np.uint8)[None, :]).tolist() == [0xDF]


def test_autosar_reference_vectors():
    # AUTOSAR SWS CRC library, CRC8H2F examples.
    vectors = {
        bytes([0x00, 0x00, 0x00, 0x00]): 0x12,
        bytes([0xF2, 0x01, 0x83]): 0xC2,
        bytes([0x0F, 0xAA, 0x00, 0x55]): 0xC6,
        bytes([0x00, 0xFF, 0x55, 0x11]): 0x77,
        bytes([0x33, 0x22, 0x55, 0xAA, 0xBB, 0xCC, 0xDD, 0xEE, 0xFF]): 0x11,
        bytes([0x92, 0x6B, 0x55]): 0x33,
        bytes([0xFF, 0xFF, 0xFF, 0xFF]): 0x6C,
    }
    for data, expected in vectors.items():
        assert crc8h2f(data) == expected, data.hex()
        assert crc8h2f_block(np.frombuffer(data, np.uint8)[None, :]).tolist() == [expected], data.hex()


def _bitwise_register(index: int) -> int:
    """Register after feeding one byte into register 0, from the polynomial 0x2F (definition)."""
    register = index
    for _ in range(8):
        register = ((register << 1) ^ 0x2F) & 0xFF if register & 0x80 else (register << 1) & 0xFF
    return register


def test_block_table_follows_the_polynomial():
    assert [int(v) for v in CRC8H2F_TABLE] == [_bitwise_register(i) for i in range(256)]


@settings(max_examples=500, deadline=None)  # no wall-clock limits: the machine is shared
@given(st.binary(max_size=64), st.integers(0, 255))
def test_scalar_path_equals_crccheck(data, init):
    assert crc8h2f(data, init) == Crc8Autosar.calc(data, init)
    assert crc8h2f(data) == Crc8Autosar.calc(data)


def test_chaining_convention():
    data = b"123456789"
    assert crc8h2f(data[4:], init=crc8h2f(data[:4]) ^ FINAL_XOR) == crc8h2f(data)


@settings(max_examples=200, deadline=None)
@given(st.integers(0, 40), st.integers(0, 12), st.integers(0, 2**32 - 1))
def test_block_path_equals_crccheck(rows, width, seed):
    rng = np.random.default_rng(seed)
    block = rng.integers(0, 256, size=(rows, width), dtype=np.uint8)
    inits = rng.integers(0, 256, size=rows, dtype=np.uint8)
    result = crc8h2f_block(block, init=inits)
    assert result.dtype == np.uint8 and result.shape == (rows,)
    assert result.tolist() == [Crc8Autosar.calc(bytes(r), int(i)) for r, i in zip(block, inits)]
    assert crc8h2f_block(block).tolist() == [Crc8Autosar.calc(bytes(r)) for r in block]


@settings(max_examples=300, deadline=None)
@given(st.lists(st.binary(min_size=7, max_size=7), min_size=1, max_size=30), st.integers(0, 255))
def test_block_path_equals_crccheck_on_drawn_rows(rows, init):
    block = np.frombuffer(b"".join(rows), dtype=np.uint8).reshape(len(rows), 7)
    assert crc8h2f_block(block, init).tolist() == [Crc8Autosar.calc(r, init) for r in rows]
