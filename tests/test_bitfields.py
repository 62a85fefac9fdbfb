"""protocol.bitfields against cantools: every layout decodes and encodes as cantools does (hypothesis)."""

from __future__ import annotations

import cantools
import numpy as np
import pytest
from cantools.database.can import Message, Signal
from cantools.database.conversion import LinearConversion
from hypothesis import given, settings
from hypothesis import strategies as st

from protocol.bitfields import BitField, BitFieldError, resolve


@st.composite
def layouts(draw):
    length = draw(st.integers(1, 64))
    big = draw(st.booleans())
    position = draw(st.integers(0, 64 - length))             # LSB (Intel) or MSB stream position (Motorola)
    start = (position // 8) * 8 + (7 - position % 8) if big else position
    signed = draw(st.booleans())
    scale = draw(st.sampled_from([1.0, 0.5, 0.001, 0.1, 2.0]))
    offset = draw(st.sampled_from([0.0, -40.0, 1.5]))
    return Signal("x", start, length, byte_order="big_endian" if big else "little_endian", is_signed=signed,
                  conversion=LinearConversion(scale, offset, False))


@settings(max_examples=300, deadline=None)
@given(layouts(), st.lists(st.binary(min_size=8, max_size=8), min_size=1, max_size=8))
def test_decode_and_encode_equal_cantools(signal, payloads):
    message = Message(0x123, "M", 8, [signal], strict=False)
    field = BitField.from_cantools(signal)
    data = np.frombuffer(b"".join(payloads), dtype=np.uint8).reshape(-1, 8).copy()
    expected = [message.decode(p, decode_choices=False)["x"] for p in payloads]
    np.testing.assert_allclose(field.decode(data), expected, rtol=1e-12)
    if signal.length > 52:              # float64 values: exact round trips up to 2**53
        return
    out = np.zeros_like(data)
    field.encode_into(out, np.asarray(expected, dtype=float))
    assert [bytes(r) for r in out] == [message.encode({"x": v}, strict=False, scaling=True) for v in expected]


def test_multiplexed_signal_resolves_with_its_multiplexer():
    db = cantools.database.load_file("protocol/dbc/foreign_robot.dbc")
    found = resolve(db, "AxisLoad", "LoadTorque_3")
    assert found.mux is not None and found.mux_value == 3
    payload = db.get_message_by_name("AxisLoad").encode({"AxisIndex": 3, "LoadTorque_3": -1.234})
    data = np.frombuffer(payload, dtype=np.uint8).reshape(1, 8)
    assert found.mux.raw(data)[0] == 3 and found.bits.decode(data)[0] == pytest.approx(-1.234)


def test_refuses_what_it_cannot_decode():
    with pytest.raises(BitFieldError, match="does not fit"):
        BitField("x", 60, 16)
    with pytest.raises(BitFieldError, match="floating-point"):
        BitField.from_cantools(Signal("f", 0, 32, conversion=LinearConversion(1.0, 0.0, True)))
    db = cantools.database.load_file("protocol/dbc/foreign_robot.dbc")
    with pytest.raises(BitFieldError, match="did you mean AxisLoad"):
        resolve(db, "AxisLod", "LoadTorque_0")
    with pytest.raises(BitFieldError, match="has no signal 'Speed'"):
        resolve(db, "AxisFeedback_0", "Speed")
