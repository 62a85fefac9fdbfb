"""DBC file vs the frame catalogue: same layout, and cantools <-> protocol round trips."""

import cantools
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from protocol import frames as F
from protocol.crc import crc8h2f
from protocol.dbc import load_database

DB = load_database()
NAMES = sorted(m.name for m in DB.messages)


def test_dbc_is_packaged_and_strict_loadable():
    assert isinstance(DB, cantools.database.can.Database)
    assert len(DB.messages) == len(F.CATALOGUE)


def test_every_dbc_frame_matches_the_catalogue():
    for message in DB.messages:
        frame_type = F.CATALOGUE[message.frame_id]
        assert message.name == frame_type.name
        assert message.length == F.FRAME_LENGTH and not message.is_extended_frame
        ours = {s.name: s for s in F.SIGNALS_BY_KIND[frame_type.kind]}
        assert {s.name for s in message.signals} == set(ours)
        for signal in message.signals:
            mine = ours[signal.name]
            assert (signal.start, signal.length, signal.is_signed, signal.byte_order) == (
                mine.start, mine.length, mine.signed, "little_endian")
            assert signal.scale == mine.scale and signal.offset == mine.offset
    assert DB.get_message_by_name("ControllerStatus").signals[2].choices[4] == "FAULT"


def _draw_signal_value(draw, signal):
    if signal.name.startswith("reserved"):  # "always 0" ([0|0] = no limits in DBC)
        return 0
    if signal.scale == 1 and signal.offset == 0:
        return draw(st.integers(int(signal.minimum), int(signal.maximum)))
    return draw(st.floats(signal.minimum, signal.maximum))


@st.composite
def cantools_frames(draw):
    message = DB.get_message_by_name(draw(st.sampled_from(NAMES)))
    values = {s.name: _draw_signal_value(draw, s) for s in message.signals}
    values["crc"] = 0
    unprotected = message.encode(values, strict=True)
    data_id = F.CATALOGUE[message.frame_id].data_id
    values["crc"] = crc8h2f(bytes([data_id & 0xFF, data_id >> 8]) + unprotected[1:])
    return message, values


def _ours_as_dict(frame) -> dict:
    fields = {name: getattr(frame, name) for name in frame.__slots__ if name != "joint"}
    return {k: int(v) if isinstance(v, F.Mode) else v for k, v in fields.items()}


@settings(max_examples=300, deadline=None)
@given(cantools_frames())
def test_cantools_encode_then_protocol_decode(drawn):
    message, values = drawn
    data = message.encode(values, strict=True)
    frame = F.decode(message.frame_id, data)
    assert not isinstance(frame, F.DecodeError), frame
    signals = {s.name: s for s in message.signals}
    for name, value in _ours_as_dict(frame).items():
        lsb = signals[name].scale
        assert abs(value - values[name]) <= lsb * (1 + 1e-9), name


@st.composite
def protocol_frames(draw):
    kind = draw(st.sampled_from(list(F.SIGNALS_BY_KIND)))
    joint = draw(st.integers(0, 7))
    if kind is F.FrameKind.MOTOR_STATE:
        frame = F.MotorState(joint, draw(st.integers(0, 255)), draw(st.floats(-1.6384, 1.63835)),
                             draw(st.floats(-655.36, 655.355)), draw(st.floats(0, 6.2828)))
    elif kind is F.FrameKind.CONTROLLER_STATUS:
        frame = F.ControllerStatus(draw(st.integers(0, 15)), draw(st.sampled_from(list(F.Mode))),
                                   draw(st.integers(0, 65535)), draw(st.integers(0, 255)),
                                   draw(st.integers(0, 2**24 - 1)))
    else:
        frame = F.JointStatus(joint, draw(st.integers(0, 15)), draw(st.floats(-1.6384, 1.63835)),
                              draw(st.floats(0, 0.51)), draw(st.floats(-327.68, 327.67)))
    return frame


@settings(max_examples=300, deadline=None)
@given(protocol_frames())
def test_protocol_encode_then_cantools_decode(frame):
    arbitration_id, data = F.encode(frame)
    message = DB.get_message_by_frame_id(arbitration_id)
    decoded = message.decode(data, decode_choices=False, scaling=True)
    assert decoded["crc"] == data[0]
    signals = {s.name: s for s in message.signals}
    for name, value in _ours_as_dict(frame).items():
        assert decoded[name] == pytest.approx(value, abs=signals[name].scale * (1 + 1e-9)), name
    for name in ("reserved", "reserved2"):
        if name in decoded:
            assert decoded[name] == 0
