"""DBC file vs the frame catalogue: same layout, physical units, readable E2E attributes, value
tables, and cantools <-> protocol round trips (values and bytes)."""

from __future__ import annotations

import math
import os
import subprocess
import sys

import cantools
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from protocol import dbc as D
from protocol import frames as F
from protocol.crc import crc8h2f

DB = D.load_database()
NAMES = sorted(m.name for m in DB.messages)
FUZZ_EXAMPLES = int(os.environ.get("FUZZ_EXAMPLES", "300"))


def test_packaged_dbc_is_the_rendered_catalogue():
    assert D.dbc_text() == D.render_dbc()


def test_dbc_is_packaged_and_strict_loadable():
    assert isinstance(DB, cantools.database.can.Database)
    assert len(DB.messages) == len(F.CATALOGUE)
    assert DB.dbc.attributes["BusType"].value == "CAN"
    assert DB.dbc.attributes["Baudrate"].value == D.BAUDRATE
    assert [n.name for n in DB.nodes] == ["Controller", "Monitor"] and all(n.comment for n in DB.nodes)


def test_every_dbc_frame_matches_the_catalogue():
    for message in DB.messages:
        frame_type = F.CATALOGUE[message.frame_id]
        assert message.name == frame_type.name
        assert message.length == F.FRAME_LENGTH and not message.is_extended_frame
        assert message.senders == ["Controller"]
        ours = {s.name: s for s in F.SIGNALS_BY_KIND[frame_type.kind]}
        assert [s.name for s in message.signals] == list(ours)
        reference = D.reference_torque_nm(message)
        assert (reference is not None) == (frame_type.joint >= 0)
        for signal in message.signals:
            mine = ours[signal.name]
            assert (signal.start, signal.length, signal.is_signed, signal.byte_order) == (
                mine.start, mine.length, mine.signed, "little_endian")
            assert signal.offset == mine.offset and (signal.unit or "") == mine.unit
            assert signal.receivers == ["Monitor"] and signal.comment
            if mine.per_reference_torque:
                assert signal.scale == pytest.approx(mine.scale * reference, rel=1e-14)
            else:
                assert signal.scale == mine.scale


def test_physical_units():
    units = {(m.name.split("_")[0], s.name): s.unit for m in DB.messages for s in m.signals}
    assert units[("MotorState", "torque")] == "Nm"
    assert units[("MotorState", "speed")] == "rad/s"
    assert units[("MotorState", "position")] == "rad"
    assert units[("JointStatus", "load_estimate")] == units[("JointStatus", "load_std")] == "Nm"
    assert units[("JointStatus", "motor_temperature")] == "degC"
    torque = DB.get_message_by_name("MotorState_0").get_signal_by_name("torque")
    assert "fraction" in torque.comment and "ReferenceTorqueNm" in torque.comment


def _role(signal) -> str:
    attribute = signal.dbc.attributes.get("SignalRole") if signal.dbc else None
    choices = DB.dbc.attribute_definitions["SignalRole"].choices
    return choices[attribute.value] if attribute else DB.dbc.attribute_definitions["SignalRole"].default_value


def test_e2e_attributes_are_readable():
    for message in DB.messages:
        frame_type = F.CATALOGUE[message.frame_id]
        attributes = message.dbc.attributes
        assert attributes["E2EDataID"].value == frame_type.data_id
        profile = DB.dbc.attribute_definitions["E2EProfile"].choices[attributes["E2EProfile"].value]
        assert profile == D.E2E_PROFILE
        roles = {s.name: _role(s) for s in message.signals}
        assert roles == {s.name: s.role.name for s in F.SIGNALS_BY_KIND[frame_type.kind]}
        assert list(roles.values()).count("E2E_CRC") == 1 and list(roles.values()).count("E2E_ALIVE_COUNTER") == 1
        counter = next(s for s in message.signals if _role(s) == "E2E_ALIVE_COUNTER")
        assert 2 ** counter.length == frame_type.counter_modulus


def test_send_type_cycle_time_and_value_tables():
    for message in DB.messages:
        kind = F.CATALOGUE[message.frame_id].kind
        assert message.send_type == "Cyclic" and message.cycle_time == D.CYCLE_TIME_MS[kind]
    status = DB.get_message_by_name("ControllerStatus")
    assert {int(k): str(v) for k, v in status.get_signal_by_name("mode").choices.items()} == \
        {int(m): m.name for m in F.Mode}
    segment = {int(k): str(v) for k, v in status.get_signal_by_name("segment").choices.items()}
    assert segment[0] == "NONE" and segment[200] == "PRODUCTION" and segment[3] == "SPEED_LEVEL_3"
    assert len(segment) == F.MAX_SPEED_LEVELS + 2


# ----------------------------------------------------------------------------------------- round trips


def _valid_frames(draw) -> tuple[int, bytes]:
    """Any catalogue frame with random field bits and a correct CRC (mode limited to defined values)."""
    arbitration_id = draw(st.sampled_from(sorted(F.CATALOGUE)))
    payload = bytearray(draw(st.binary(min_size=8, max_size=8)))
    kind = F.CATALOGUE[arbitration_id].kind
    if kind is F.FrameKind.CONTROLLER_STATUS:
        payload[1] = (payload[1] & 0x0F) | (draw(st.sampled_from(list(F.Mode))) << 4)
    if kind is F.FrameKind.JOINT_STATUS:
        payload[1] &= 0x0F
        payload[7] = 0
    payload[0] = F.frame_crc(arbitration_id, payload)
    return arbitration_id, bytes(payload)


valid_frames = st.composite(_valid_frames)


def _protocol_values(frame, message) -> dict[str, float]:
    """Decoded protocol record as DBC physical values (fractions -> Nm)."""
    fields = {name: getattr(frame, name) for name in frame.__slots__ if name != "joint"}
    reference = D.reference_torque_nm(message)
    signals = {s.name: s for s in F.SIGNALS_BY_KIND[F.CATALOGUE[message.frame_id].kind]}
    return {k: (float(v) * reference if signals[k].per_reference_torque else int(v) if isinstance(v, F.Mode) else v)
            for k, v in fields.items()}


@settings(max_examples=FUZZ_EXAMPLES, deadline=None)
@given(valid_frames())
def test_cantools_and_protocol_decode_every_frame_identically(drawn):
    arbitration_id, data = drawn
    message = DB.get_message_by_frame_id(arbitration_id)
    frame = F.decode(arbitration_id, data)
    assert not isinstance(frame, F.DecodeError), frame
    decoded = message.decode(data, decode_choices=False, scaling=True)
    for name, value in _protocol_values(frame, message).items():
        assert decoded[name] == pytest.approx(value, rel=1e-12, abs=1e-12), name
    assert decoded["crc"] == data[0]
    raw = message.decode(data, decode_choices=False, scaling=False)
    assert message.encode(raw, scaling=False, strict=True) == data
    assert message.encode(decoded, strict=True) == data  # physical values (Nm, rad/s, ...) back to bytes


@settings(max_examples=FUZZ_EXAMPLES, deadline=None)
@given(valid_frames())
def test_protocol_block_decoder_agrees_with_cantools(drawn):
    arbitration_id, data = drawn
    message = DB.get_message_by_frame_id(arbitration_id)
    block = F.decode_block(np.array([arbitration_id]), np.frombuffer(data, np.uint8)[None, :], np.array([8]))
    decoded = message.decode(data, decode_choices=False)
    reference = D.reference_torque_nm(message)
    kind = F.CATALOGUE[arbitration_id].kind
    if kind is F.FrameKind.MOTOR_STATE:
        assert block.torque[0] * reference == pytest.approx(decoded["torque"], rel=1e-12, abs=1e-12)
        assert block.speed[0] == pytest.approx(decoded["speed"], rel=1e-12, abs=1e-12)
    elif kind is F.FrameKind.JOINT_STATUS:
        assert block.load_std[0] * reference == pytest.approx(decoded["load_std"], rel=1e-12, abs=1e-12)
        assert block.motor_temperature[0] == pytest.approx(decoded["motor_temperature"], abs=1e-9)
    else:
        assert (block.mode[0], block.status_tick[0]) == (decoded["mode"], decoded["tick"])


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
    data_id = message.dbc.attributes["E2EDataID"].value
    values["crc"] = crc8h2f(bytes([data_id & 0xFF, data_id >> 8]) + unprotected[1:])
    return message, values


@settings(max_examples=FUZZ_EXAMPLES, deadline=None)
@given(cantools_frames())
def test_cantools_encode_then_protocol_decode(drawn):
    message, values = drawn
    data = message.encode(values, strict=True)
    frame = F.decode(message.frame_id, data)
    assert not isinstance(frame, F.DecodeError), frame
    signals = {s.name: s for s in message.signals}
    for name, value in _protocol_values(frame, message).items():
        assert abs(value - values[name]) <= signals[name].scale * (1 + 1e-9), name


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


@settings(max_examples=FUZZ_EXAMPLES, deadline=None)
@given(protocol_frames())
def test_protocol_encode_then_cantools_decode(frame):
    arbitration_id, data = F.encode(frame)
    message = DB.get_message_by_frame_id(arbitration_id)
    decoded = message.decode(data, decode_choices=False, scaling=True)
    assert decoded["crc"] == data[0]
    signals = {s.name: s for s in message.signals}
    for name, value in _protocol_values(frame, message).items():
        assert decoded[name] == pytest.approx(value, abs=signals[name].scale * (1 + 1e-9)), name
    for name in ("reserved", "reserved2"):
        if name in decoded:
            assert decoded[name] == 0


# ------------------------------------------------------------------------- DBC for a given robot


def test_render_for_a_robot_scales_torque_per_joint_and_keeps_the_wire_format():
    references = [2500.0, 2500.0, 1200.0, 400.0, 400.0, 200.0]
    db = D.load_database(D.render_dbc(references))
    data = F.encode_motor_state(2, 7, 0.5, 10.0, 1.0)
    assert db.get_message_by_name("MotorState_2").decode(data)["torque"] == pytest.approx(600.0)
    assert D.reference_torque_nm(db.get_message_by_name("JointStatus_5")) == 200.0
    assert D.reference_torque_nm(db.get_message_by_name("MotorState_7")) == D.NOMINAL_REFERENCE_TORQUE_NM
    for message in db.messages:      # same layout as the packaged DBC, only factors and limits differ
        packaged = DB.get_message_by_frame_id(message.frame_id)
        assert [(s.name, s.start, s.length, s.is_signed) for s in message.signals] == \
            [(s.name, s.start, s.length, s.is_signed) for s in packaged.signals]
    torque = db.get_message_by_name("MotorState_0").get_signal_by_name("torque")
    assert math.isclose(torque.scale, F.TORQUE_SCALE * 2500.0) and torque.maximum == pytest.approx(4095.875)


@pytest.mark.parametrize("bad", [0.0, -5.0, [1.0] * 9, [], [100.0, float("nan")]])
def test_render_rejects_bad_reference_torques(bad):
    with pytest.raises(ValueError, match="reference torques in Nm"):
        D.render_dbc(bad)


def test_command_line_writes_a_dbc_and_reports_bad_values(tmp_path):
    out = tmp_path / "robot.dbc"
    ok = subprocess.run([sys.executable, "-m", "protocol.dbc", "--reference-torque", "300,300,150",
                         "--out", str(out)], capture_output=True, text=True, timeout=120)
    assert ok.returncode == 0, ok.stderr
    assert D.reference_torque_nm(D.load_database(out.read_text()).get_message_by_name("MotorState_2")) == 150.0
    bad = subprocess.run([sys.executable, "-m", "protocol.dbc", "--reference-torque", "300,abc"],
                         capture_output=True, text=True, timeout=120)
    assert bad.returncode == 2 and "--reference-torque 300,abc" in bad.stderr and "Traceback" not in bad.stderr


def test_cantools_decode_command_reads_a_recording(tmp_path):
    """`cantools decode DBC < candump.log` shows named values with units."""
    lines = []
    for arbitration_id, data in ((0x100, F.encode_motor_state(0, 3, 0.25, 12.5, 1.0)),
                                 (0x080, F.encode_controller_status(1, F.Mode.TEST_CYCLE, 4, 3, 30)),
                                 (0x0A0, F.encode_joint_status(0, 1, 0.4, 0.1, 36.5))):
        lines.append(f"(0.000000) can0 {arbitration_id:03X}#{data.hex().upper()}")
    dbc_path = tmp_path / "robot_joints.dbc"
    dbc_path.write_text(D.dbc_text())
    result = subprocess.run([sys.executable, "-m", "cantools", "decode", str(dbc_path)], input="\n".join(lines),
                            capture_output=True, text=True, timeout=120)
    assert result.returncode == 0, result.stderr
    out = result.stdout
    assert "torque: 25.0 Nm" in out and "speed: 12.5 rad/s" in out
    assert "mode: TEST_CYCLE" in out and "segment: SPEED_LEVEL_3" in out
    assert "load_estimate: 40.0 Nm" in out and "motor_temperature: 36.5 degC" in out


# ------------------------------------------------------------------------- a real recording, read by cantools


@pytest.fixture(scope="module")
def recorded_log(tmp_path_factory):
    """A candump .log of the simulated controller: 2 joints, 1 test cycle (≈ 39,000 frames)."""
    path = tmp_path_factory.mktemp("recording") / "x.log"
    result = subprocess.run([sys.executable, "-m", "sim_controller.cli", "record", "--joints", "2", "--cycles", "1",
                             "--out", str(path), "-q"], capture_output=True, text=True, timeout=300)
    assert result.returncode == 0, result.stderr
    return path


def _role_of(message, role: str):
    return next(s for s in message.signals if _role(s) == role)


def test_cantools_decodes_every_frame_of_a_recording_with_zero_e2e_errors(recorded_log):
    """Every frame of a real recording decodes with the shipped DBC; its CRC, computed by crccheck from
    the DBC's E2EDataID attribute, matches; its alive counter (the signal whose SignalRole is
    E2E_ALIVE_COUNTER) steps by one modulo 2^length per message."""
    import can
    from crccheck.crc import Crc8Autosar

    frames = crc_errors = counter_errors = 0
    last_counter: dict[int, int] = {}
    kinds: set[str] = set()
    with can.LogReader(str(recorded_log)) as reader:
        for msg in reader:
            message = DB.get_message_by_frame_id(msg.arbitration_id)    # KeyError: unknown frame
            decoded = message.decode(bytes(msg.data), decode_choices=True)     # DecodeError: short frame
            frames += 1
            kinds.add(message.name.split("_")[0])
            data_id = message.dbc.attributes["E2EDataID"].value
            crc_signal = _role_of(message, "E2E_CRC")
            expected = Crc8Autosar.calc(bytes([data_id & 0xFF, data_id >> 8]) + bytes(msg.data[1:]))
            crc_errors += decoded[crc_signal.name] != expected
            counter = _role_of(message, "E2E_ALIVE_COUNTER")
            value = int(decoded[counter.name])
            if msg.arbitration_id in last_counter:
                counter_errors += value != (last_counter[msg.arbitration_id] + 1) % 2 ** counter.length
            last_counter[msg.arbitration_id] = value
            if message.name == "ControllerStatus":
                assert str(decoded["mode"]) in {m.name for m in F.Mode}
    assert frames > 30_000 and kinds == {"MotorState", "ControllerStatus", "JointStatus"}
    assert (crc_errors, counter_errors) == (0, 0)


def test_cantools_decode_command_reads_a_real_recording(recorded_log):
    """`cantools decode --single-line DBC < recording.log`: one decoded line per frame, physical units
    and named states, no undecodable frame."""
    dbc_path = recorded_log.parent / "robot_joints.dbc"
    dbc_path.write_text(D.dbc_text())
    with open(recorded_log) as stdin:
        result = subprocess.run([sys.executable, "-m", "cantools", "decode", "--single-line", str(dbc_path)],
                                stdin=stdin, capture_output=True, text=True, timeout=300)
    assert result.returncode == 0, result.stderr
    lines = result.stdout.splitlines()
    assert len(lines) == sum(1 for _ in open(recorded_log)) > 30_000
    assert all(" :: " in line and "Unknown" not in line for line in lines)
    motor = next(line for line in lines if "MotorState_1(" in line)
    assert " Nm, speed: " in motor and " rad/s, position: " in motor and motor.endswith(" rad)")
    assert any("mode: TEST_CYCLE" in line and "segment: SPEED_LEVEL_" in line for line in lines)
    assert any("load_estimate: " in line and " degC" in line for line in lines)
