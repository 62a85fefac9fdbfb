"""Frame catalogue: scalar vs block codecs, saturation, bad input, fuzzing, bit-flip detection."""

import itertools
import math
import os

import can
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from protocol import frames as F
from protocol.crc import crc8h2f

finite_or_inf = st.floats(allow_nan=False, allow_infinity=True, width=64)
moderate = st.floats(-1e6, 1e6, allow_nan=False)


def representative_frames() -> list[tuple[int, bytes]]:
    """One frame of every catalogue ID with non-trivial field values."""
    out = [(F.CONTROLLER_STATUS_ID, F.encode_controller_status(7, F.Mode.TEST_CYCLE, 1234, 17, 9_876_543))]
    for j in range(F.MAX_JOINTS):
        out.append((F.MOTOR_STATE_BASE_ID + j, F.encode_motor_state(j, 1000 + j, -0.3 + j / 10, 123.4 - 40 * j, j)))
        out.append((F.JOINT_STATUS_BASE_ID + j, F.encode_joint_status(j, j + 3, 0.2 - j / 20, 0.01 * j, 40 + j)))
    return out


# --------------------------------------------------------------------------- catalogue and layout


def test_catalogue_ids_and_data_ids_follow_protocol_md():
    assert F.CATALOGUE[0x080].data_id == 0x1080
    for j in range(8):
        assert F.CATALOGUE[0x100 + j].data_id == 0x1100 + j
        assert F.CATALOGUE[0x0A0 + j].data_id == 0x10A0 + j
        assert F.CATALOGUE[0x100 + j].counter_modulus == 256
        assert F.CATALOGUE[0x0A0 + j].counter_modulus == 16
    assert len(F.CATALOGUE) == 17
    assert all(i < 0x800 for i in F.CATALOGUE)


@pytest.mark.parametrize("signals", F.SIGNALS_BY_KIND.values())
def test_signals_tile_the_64_bits_without_overlap(signals):
    bits = [b for s in signals for b in range(s.start, s.start + s.length)]
    assert sorted(bits) == list(range(64))


def test_scaling_meets_issue_requirements():
    assert F.TORQUE_SCALE <= 1e-4
    assert F.SPEED_SCALE <= 0.01
    assert (2**17 - 1) * F.SPEED_SCALE >= 400


def test_crc_is_over_data_id_then_payload_bytes_1_to_7():
    data = F.encode_motor_state(3, 5, 0.1, 2.0, 1.0)
    assert data[0] == crc8h2f(bytes([0x03, 0x11]) + data[1:])
    status = F.encode_controller_status(1, F.Mode.PRODUCTION, 2, F.SEGMENT_PRODUCTION, 3)
    assert status[0] == crc8h2f(bytes([0x80, 0x10]) + status[1:])
    for arbitration_id, payload in representative_frames():
        assert F.frame_crc(arbitration_id, payload) == payload[0]


def test_to_message_is_classical_11_bit():
    msg = F.to_message(0x101, F.encode_motor_state(1, 0, 0, 0, 0), timestamp=1.5)
    assert msg.is_extended_id is False and msg.dlc == 8 and msg.timestamp == 1.5 and not msg.is_fd


# --------------------------------------------------------------------------- scalar round trips


@settings(deadline=None)  # no wall-clock limits: the machine is shared
@given(st.integers(0, 7), st.integers(0, 2**40), st.floats(-1.6384, 1.6383), st.floats(-655.36, 655.35),
       st.floats(0, 2 * math.pi * 16383 / 16384))
def test_motor_state_round_trip_within_half_lsb(joint, tick, torque, speed, position):
    frame = F.decode(0x100 + joint, F.encode_motor_state(joint, tick, torque, speed, position))
    assert isinstance(frame, F.MotorState)
    assert frame.joint == joint and frame.tick == tick % 256
    assert abs(frame.torque - torque) <= F.TORQUE_SCALE / 2 + 1e-12
    assert abs(frame.speed - speed) <= F.SPEED_SCALE / 2 + 1e-9
    # position is modulo one revolution: compare on the circle
    diff = (frame.position - position + math.pi) % (2 * math.pi) - math.pi
    assert abs(diff) <= F.POSITION_SCALE / 2 + 1e-12


@settings(deadline=None)  # no wall-clock limits: the machine is shared
@given(st.integers(0, 2**20), st.sampled_from(list(F.Mode)), st.integers(0, 2**20), st.integers(0, 255),
       st.integers(0, 2**30))
def test_controller_status_round_trip(counter, mode, cycle, segment, tick):
    frame = F.decode(0x080, F.encode_controller_status(counter, mode, cycle, segment, tick))
    assert frame == F.ControllerStatus(counter % 16, mode, cycle % 65536, segment, tick % 2**24)


@settings(deadline=None)  # no wall-clock limits: the machine is shared
@given(st.integers(0, 7), st.integers(0, 100), st.floats(-1.6384, 1.6383), st.floats(0, 0.51),
       st.floats(-327.68, 327.67))
def test_joint_status_round_trip(joint, counter, load, load_std, temperature):
    frame = F.decode(0x0A0 + joint, F.encode_joint_status(joint, counter, load, load_std, temperature))
    assert isinstance(frame, F.JointStatus)
    assert frame.counter == counter % 16
    assert abs(frame.load_estimate - load) <= F.TORQUE_SCALE / 2 + 1e-12
    assert abs(frame.load_std - load_std) <= F.LOAD_STD_SCALE / 2 + 1e-12
    assert abs(frame.motor_temperature - temperature) <= F.TEMPERATURE_SCALE / 2 + 1e-9


def test_encoders_saturate_out_of_range_values():
    frame = F.decode(0x100, F.encode_motor_state(0, 0, 5.0, -math.inf, 0.0))
    assert frame.torque == pytest.approx((2**15 - 1) * F.TORQUE_SCALE)
    assert frame.speed == pytest.approx(-(2**17) * F.SPEED_SCALE)
    status = F.decode(0x0A1, F.encode_joint_status(1, 0, -9.0, 3.0, 1000.0))
    assert status.load_estimate == pytest.approx(-1.6384)
    assert status.load_std == pytest.approx(0.51)
    assert status.motor_temperature == pytest.approx(327.67)


def test_position_wraps_modulo_one_revolution():
    assert F.decode(0x100, F.encode_motor_state(0, 0, 0, 0, 2 * math.pi + 1.0)).position == pytest.approx(1.0, abs=2e-4)
    assert F.decode(0x100, F.encode_motor_state(0, 0, 0, 0, -1.0)).position == pytest.approx(2 * math.pi - 1.0, abs=2e-4)


@pytest.mark.parametrize(
    ("call", "field"),
    [
        (lambda: F.encode_motor_state(0, 0, math.nan, 0, 0), "torque"),
        (lambda: F.encode_motor_state(0, 0, 0, math.nan, 0), "speed"),
        (lambda: F.encode_motor_state(0, 0, 0, 0, math.inf), "position"),
        (lambda: F.encode_motor_state(8, 0, 0, 0, 0), "joint"),
        (lambda: F.encode_motor_state(-1, 0, 0, 0, 0), "joint"),
        (lambda: F.encode_motor_state(0, -1, 0, 0, 0), "tick"),
        (lambda: F.encode_controller_status(0, 9, 0, 0, 0), "mode"),
        (lambda: F.encode_controller_status(0, 1, 0, 256, 0), "segment"),
        (lambda: F.encode_joint_status(0, 0, 0, math.nan, 0), "load_std"),
        (lambda: F.encode_joint_status(0, 0, 0, 0, math.nan), "motor_temperature"),
        (lambda: F.encode_motor_state_block(0, np.arange(3), [0, np.nan, 0], [0, 0, 0], [0, 0, 0]), "torque"),
        (lambda: F.encode_motor_state_block(9, np.arange(1), [0], [0], [0]), "joint"),
    ],
)
def test_bad_encoder_input_raises_value_error_naming_the_field(call, field):
    with pytest.raises(F.FrameValueError, match=field) as info:
        call()
    assert isinstance(info.value, ValueError)


def test_encode_of_records_matches_encoders():
    for arbitration_id, data in representative_frames():
        frame = F.decode(arbitration_id, data)
        assert F.encode(frame) == (arbitration_id, data)


# --------------------------------------------------------------------------- block vs scalar


@settings(max_examples=60, deadline=None)
@given(st.lists(st.tuples(st.integers(0, 7), st.integers(0, 2**31), finite_or_inf, finite_or_inf, moderate),
                min_size=1, max_size=30))
def test_block_encoder_equals_scalar_encoder(rows):
    joints, ticks, torque, speed, position = (np.array(c) for c in zip(*rows))
    block = F.encode_motor_state_block(joints, ticks.astype(np.int64), torque, speed, position)
    assert block.dtype == np.uint8 and block.shape == (len(rows), 8)
    for row, (j, t, tq, sp, pos) in zip(block, rows):
        assert bytes(row) == F.encode_motor_state(j, t, tq, sp, pos)


def _assert_block_row_equals_scalar(block: F.DecodedBlock, i: int, frame) -> None:
    if isinstance(frame, F.DecodeError):
        assert block.kind[i] == F.FrameKind.ERROR and block.error[i] == frame.kind
        assert block.counter[i] == -1
        return
    assert block.error[i] == F.DecodeErrorKind.NONE and block.crc_ok[i]
    if isinstance(frame, F.MotorState):
        assert block.kind[i] == F.FrameKind.MOTOR_STATE
        got = (block.joint[i], block.counter[i], block.torque[i], block.speed[i], block.position[i])
        assert got == (frame.joint, frame.tick, frame.torque, frame.speed, frame.position)
    elif isinstance(frame, F.ControllerStatus):
        assert block.kind[i] == F.FrameKind.CONTROLLER_STATUS
        got = (block.counter[i], block.mode[i], block.cycle[i], block.segment[i], block.status_tick[i])
        assert got == (frame.counter, frame.mode, frame.cycle, frame.segment, frame.tick)
    else:
        assert block.kind[i] == F.FrameKind.JOINT_STATUS
        got = (block.joint[i], block.counter[i], block.load_estimate[i], block.load_std[i], block.motor_temperature[i])
        assert got == (frame.joint, frame.counter, frame.load_estimate, frame.load_std, frame.motor_temperature)


frame_rows = st.one_of(
    st.tuples(st.integers(-5, 0x900), st.binary(min_size=0, max_size=12)),  # garbage
    st.sampled_from(representative_frames()),  # valid frames
    st.tuples(st.sampled_from(sorted(F.CATALOGUE)), st.binary(min_size=8, max_size=8)),  # known id, random bytes
)


@settings(max_examples=150, deadline=None)
@given(st.lists(frame_rows, min_size=1, max_size=40))
def test_block_decoder_equals_scalar_decoder_on_arbitrary_rows(rows):
    ids = np.array([r[0] for r in rows])
    data = np.array([list(r[1][:8].ljust(8, b"\0")) for r in rows], dtype=np.uint8)
    dlc = np.array([len(r[1]) for r in rows])
    block = F.decode_block(ids, data, dlc)
    assert len(block) == len(rows)
    for i, (arbitration_id, payload) in enumerate(rows):
        _assert_block_row_equals_scalar(block, i, F.decode(arbitration_id, payload))


# --------------------------------------------------------------------------- bad input never raises


@settings(max_examples=300, deadline=None)
@given(st.one_of(st.integers(), st.none(), st.text(max_size=3), st.floats()),
       st.one_of(st.binary(max_size=70), st.lists(st.integers(-300, 300), max_size=10), st.none(), st.text(max_size=9)))
def test_decode_never_raises(arbitration_id, data):
    result = F.decode(arbitration_id, data)
    assert isinstance(result, (F.MotorState, F.ControllerStatus, F.JointStatus, F.DecodeError))


def test_decode_reports_each_error_kind():
    good = F.encode_motor_state(0, 1, 0.1, 0.2, 0.3)
    assert F.decode(0x7FF, good).kind == F.DecodeErrorKind.UNKNOWN_ID
    assert F.decode(0x100, good[:7]).kind == F.DecodeErrorKind.WRONG_DLC
    assert F.decode(0x100, good + b"\0").kind == F.DecodeErrorKind.WRONG_DLC
    assert F.decode(0x101, good).kind == F.DecodeErrorKind.CRC  # masquerade as another joint
    # a CRC-correct controller status carrying an undefined mode
    word = (9 << 12) | (1 << 8)
    payload = word.to_bytes(8, "little")[1:]
    bad_mode = bytes([crc8h2f(bytes([0x80, 0x10]) + payload)]) + payload
    assert F.decode(0x080, bad_mode).kind == F.DecodeErrorKind.BAD_VALUE


def test_decode_message_flags_extended_remote_and_error_frames():
    data = F.encode_motor_state(0, 1, 0.1, 0.2, 0.3)
    assert isinstance(F.decode_message(F.to_message(0x100, data)), F.MotorState)
    for msg in (can.Message(arbitration_id=0x100, data=data, is_extended_id=True),
                can.Message(arbitration_id=0x100, is_extended_id=False, is_remote_frame=True, dlc=8),
                can.Message(arbitration_id=0x100, data=data, is_extended_id=False, is_error_frame=True)):
        assert F.decode_message(msg).kind == F.DecodeErrorKind.UNKNOWN_ID
    assert isinstance(F.decode_message("not a message"), F.DecodeError)


def test_messages_to_arrays_pads_and_flags():
    good = F.encode_motor_state(2, 7, 0.5, 1.0, 2.0)
    msgs = [
        F.to_message(0x102, good, timestamp=1.0),
        can.Message(arbitration_id=0x102, data=good[:5], is_extended_id=False, timestamp=2.0),
        can.Message(arbitration_id=0x102, data=good, is_extended_id=True, timestamp=3.0),
    ]
    ids, data, dlc, timestamps = F.messages_to_arrays(msgs)
    assert data.shape == (3, 8) and data.dtype == np.uint8
    assert dlc.tolist() == [8, 5, 8] and timestamps.tolist() == [1.0, 2.0, 3.0]
    assert bytes(data[1]) == good[:5] + b"\0\0\0"
    block = F.decode_block(ids, data, dlc)
    assert block.error.tolist() == [F.DecodeErrorKind.NONE, F.DecodeErrorKind.WRONG_DLC, F.DecodeErrorKind.UNKNOWN_ID]
    assert block.error_counts() == {"UNKNOWN_ID": 1, "WRONG_DLC": 1, "CRC": 0, "BAD_VALUE": 0}
    empty = F.messages_to_arrays([])
    assert [a.shape[0] for a in empty] == [0, 0, 0, 0]
    assert len(F.decode_block(*empty[:3])) == 0


# --------------------------------------------------------------------------- bit-flip detection


def _flipped_rows(payload: bytes, n_flips: int) -> np.ndarray:
    """All variants of ``payload`` with exactly ``n_flips`` of its 64 bits inverted."""
    word = int.from_bytes(payload, "little")
    combos = np.array(list(itertools.combinations(range(64), n_flips)), dtype=np.uint64)
    masks = np.bitwise_or.reduce(np.uint64(1) << combos, axis=1)
    words = np.uint64(word) ^ masks
    return words.astype("<u8").view(np.uint8).reshape(-1, 8)


@pytest.mark.parametrize("n_flips", [1, 2, 3])
def test_every_single_double_and_triple_bit_flip_is_detected(n_flips):
    """Exhaustive over the 56 payload bits + 8 CRC bits of one frame of every ID.

    CRC-8H2F (0x2F) has Hamming distance 4 for data up to 119 bits (Koopman's tables); our CRC
    input is 72 bits (16-bit data ID + 56 payload bits), so every error of 1, 2 or 3 bits —
    including flips in the alive counter — changes the CRC.  There is no "valid by construction"
    exception: the counter is inside the protected bytes.
    """
    for arbitration_id, payload in representative_frames():
        rows = _flipped_rows(payload, n_flips)
        block = F.decode_block(np.full(len(rows), arbitration_id), rows, np.full(len(rows), 8))
        assert not block.crc_ok.any(), f"undetected {n_flips}-bit error in 0x{arbitration_id:X}"
        assert (block.error == F.DecodeErrorKind.CRC).all()


def test_a_frame_of_one_joint_is_rejected_under_any_other_joint_id():
    """Data IDs of joints 0..7 differ in at most 3 bits, so masquerading is always detected."""
    for arbitration_id, payload in representative_frames():
        frame_type = F.CATALOGUE[arbitration_id]
        for other in F.CATALOGUE.values():
            if other.kind == frame_type.kind and other.arbitration_id != arbitration_id:
                assert F.decode(other.arbitration_id, payload).kind == F.DecodeErrorKind.CRC


@settings(max_examples=60, deadline=None)
@given(st.lists(st.tuples(st.integers(0, 2**20), st.sampled_from(list(F.Mode)), st.integers(0, 2**20),
                          st.integers(0, 255), st.integers(0, 2**30)), min_size=1, max_size=20))
def test_controller_status_block_encoder_equals_scalar(rows):
    columns = [np.array([int(v) for v in c]) for c in zip(*rows)]
    block = F.encode_controller_status_block(*columns)
    assert [bytes(r) for r in block] == [F.encode_controller_status(*row) for row in rows]


@settings(max_examples=60, deadline=None)
@given(st.lists(st.tuples(st.integers(0, 7), st.integers(0, 2**20), finite_or_inf, finite_or_inf, finite_or_inf),
                min_size=1, max_size=20))
def test_joint_status_block_encoder_equals_scalar(rows):
    columns = [np.array(c) for c in zip(*rows)]
    block = F.encode_joint_status_block(*columns)
    assert [bytes(r) for r in block] == [F.encode_joint_status(*row) for row in rows]


def test_status_block_encoders_reject_bad_columns():
    with pytest.raises(F.FrameValueError, match="mode"):
        F.encode_controller_status_block([0], [7], [0], [0], [0])
    with pytest.raises(F.FrameValueError, match="segment"):
        F.encode_controller_status_block([0], [1], [0], [300], [0])
    with pytest.raises(F.FrameValueError, match="load_std"):
        F.encode_joint_status_block([0], [0], [0.0], [np.nan], [20.0])
    with pytest.raises(F.FrameValueError, match="joint"):
        F.encode_joint_status_block([8], [0], [0.0], [0.0], [20.0])


# --------------------------------------------------------------------------- fuzzing the decoders

FUZZ_EXAMPLES = int(os.environ.get("FUZZ_EXAMPLES", "300"))  # FUZZ_EXAMPLES=20000 locally


@settings(max_examples=FUZZ_EXAMPLES, deadline=None)
@given(st.lists(st.tuples(st.one_of(st.sampled_from(sorted(F.CATALOGUE)), st.integers(-2**63, 2**63 - 1)),
                          st.binary(min_size=8, max_size=8), st.integers(-2**31, 2**31 - 1)), max_size=30))
def test_block_decoder_on_random_ids_bytes_and_dlc(rows):
    """Any id, any 8 bytes, any DLC (also negative or > 8): rows fail with the right kind, never raise."""
    ids = np.array([r[0] for r in rows], dtype=np.int64)
    data = np.frombuffer(b"".join(r[1] for r in rows), dtype=np.uint8).reshape(len(rows), 8)
    dlc = np.array([r[2] for r in rows], dtype=np.int64)
    block = F.decode_block(ids, data, dlc)
    assert len(block) == len(rows)
    for i, (arbitration_id, payload, length) in enumerate(rows):
        if arbitration_id not in F.CATALOGUE:
            assert block.error[i] == F.DecodeErrorKind.UNKNOWN_ID
        elif length != 8:
            assert block.error[i] == F.DecodeErrorKind.WRONG_DLC
        else:
            scalar = F.decode(arbitration_id, payload)
            assert block.error[i] == (scalar.kind if isinstance(scalar, F.DecodeError) else F.DecodeErrorKind.NONE)
        assert block.valid[i] == (block.error[i] == F.DecodeErrorKind.NONE)
        assert (block.counter[i] >= 0) == bool(block.valid[i])


@settings(max_examples=FUZZ_EXAMPLES, deadline=None)
@given(st.integers(0, 0x7FF), st.binary(max_size=64), st.integers(0, 64), st.booleans(), st.booleans(),
       st.booleans(), st.booleans())
def test_message_decoders_on_random_messages(arbitration_id, payload, dlc, extended, remote, error, fd):
    """python-can messages with any data length, DLC and flags: both decoders agree, nothing raises."""
    message = can.Message(arbitration_id=arbitration_id, data=payload, dlc=dlc, is_extended_id=extended,
                          is_remote_frame=remote, is_error_frame=error, is_fd=fd, check=False)
    scalar = F.decode_message(message)
    ids, data, lengths, _ = F.messages_to_arrays([message])
    block = F.decode_block(ids, data, lengths)
    if isinstance(scalar, F.DecodeError):
        assert block.error[0] == scalar.kind
    else:
        assert block.error[0] == F.DecodeErrorKind.NONE and len(payload) == 8
