"""Frame catalogue, scaling, encoders and decoders (docs/PROTOCOL.md).

Layout: a frame's 8 bytes are one little-endian uint64 ``w``; a field of ``n`` bits at start bit
``b`` is ``(w >> b) & (2**n - 1)`` (signed fields are two's complement).  Byte 0 is the E2E CRC
(CRC-8H2F over the data ID, low byte first, then bytes 1..7); every frame has an alive counter.

Encoders saturate physical values to the representable range and round to the nearest step;
NaN (or a joint outside 0..7) raises ``FrameValueError`` naming the field.  Decoders never raise:
bad input yields a ``DecodeError`` with a ``DecodeErrorKind``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from enum import IntEnum
from operator import attrgetter
from typing import Iterable, Sequence

import can
import numpy as np

from protocol.crc import FINAL_XOR, crc8h2f, crc8h2f_block

MAX_JOINTS = 8
FRAME_LENGTH = 8
MOTOR_STATE_BASE_ID = 0x100
CONTROLLER_STATUS_ID = 0x080
JOINT_STATUS_BASE_ID = 0x0A0
MOTOR_STATE_DATA_ID_BASE = 0x1100
CONTROLLER_STATUS_DATA_ID = 0x1080
JOINT_STATUS_DATA_ID_BASE = 0x10A0

MOTOR_COUNTER_MODULUS = 256  # MotorState.tick = controller tick mod 256
STATUS_COUNTER_MODULUS = 16  # 4-bit alive counters of the status frames
CYCLE_MODULUS = 1 << 16
STATUS_TICK_MODULUS = 1 << 24

TORQUE_SCALE = 5e-5  # fraction of the joint's reference (maximum) torque per LSB
SPEED_SCALE = 0.005  # rad/s (motor side) per LSB
POSITION_SCALE = 2.0 * math.pi / 16384  # rad per LSB
LOAD_STD_SCALE = 0.002  # fraction of the reference torque per LSB
TEMPERATURE_SCALE = 0.01  # degC per LSB

SEGMENT_NONE = 0
SEGMENT_PRODUCTION = 200
MAX_SPEED_LEVELS = 64


class Mode(IntEnum):
    """Controller mode (ControllerStatus.mode)."""

    INIT = 0
    TEST_CYCLE = 1
    PRODUCTION = 2
    STOPPED = 3
    FAULT = 4


class FrameKind(IntEnum):
    """Row kind in a ``DecodedBlock``; ``ERROR`` marks rows that failed decoding."""

    ERROR = 0
    MOTOR_STATE = 1
    CONTROLLER_STATUS = 2
    JOINT_STATUS = 3


class DecodeErrorKind(IntEnum):
    """Why a frame was rejected (``NONE`` = decoded fine)."""

    NONE = 0
    UNKNOWN_ID = 1  # not in the catalogue (also extended / remote / error frames)
    WRONG_DLC = 2  # data length is not 8
    CRC = 3  # CRC-8H2F over data ID + payload does not match byte 0
    BAD_VALUE = 4  # CRC fine but a field holds a value outside its definition (e.g. mode 9)


class FrameValueError(ValueError):
    """A value handed to an encoder cannot be put on the wire (message names the field)."""


class SignalRole(IntEnum):
    """What a field is for (the DBC's ``SignalRole`` attribute)."""

    DATA = 0
    E2E_CRC = 1  # CRC-8H2F over data ID + bytes 1..7
    E2E_ALIVE_COUNTER = 2  # increments by one per frame of the identifier (wrapping)
    RESERVED = 3  # always 0


@dataclass(frozen=True, slots=True)
class Signal:
    """One field of a frame: bit position, width, scaling (value = raw * scale + offset), unit, role.

    ``per_reference_torque`` fields carry a torque as a fraction of the joint's reference torque
    (its maximum): ``scale`` is in fractions per LSB, which is what the decoders return, and the
    physical value on the bus is that fraction times the reference torque, in ``unit`` (Nm); the
    DBC's factor is ``scale`` × its message's ``ReferenceTorqueNm`` attribute.
    """

    name: str
    start: int
    length: int
    signed: bool = False
    scale: float = 1.0
    offset: float = 0.0
    unit: str = ""
    role: SignalRole = SignalRole.DATA
    per_reference_torque: bool = False

    @property
    def raw_min(self) -> int:
        return -(1 << (self.length - 1)) if self.signed else 0

    @property
    def raw_max(self) -> int:
        return (1 << (self.length - 1)) - 1 if self.signed else (1 << self.length) - 1


_CRC = Signal("crc", 0, 8, role=SignalRole.E2E_CRC)
MOTOR_STATE_SIGNALS: tuple[Signal, ...] = (
    _CRC,
    Signal("tick", 8, 8, role=SignalRole.E2E_ALIVE_COUNTER),
    Signal("torque", 16, 16, True, TORQUE_SCALE, unit="Nm", per_reference_torque=True),
    Signal("speed", 32, 18, True, SPEED_SCALE, unit="rad/s"),
    Signal("position", 50, 14, False, POSITION_SCALE, unit="rad"),
)
CONTROLLER_STATUS_SIGNALS: tuple[Signal, ...] = (
    _CRC,
    Signal("counter", 8, 4, role=SignalRole.E2E_ALIVE_COUNTER),
    Signal("mode", 12, 4),
    Signal("cycle", 16, 16),
    Signal("segment", 32, 8),
    Signal("tick", 40, 24),
)
JOINT_STATUS_SIGNALS: tuple[Signal, ...] = (
    _CRC,
    Signal("counter", 8, 4, role=SignalRole.E2E_ALIVE_COUNTER),
    Signal("reserved", 12, 4, role=SignalRole.RESERVED),
    Signal("load_estimate", 16, 16, True, TORQUE_SCALE, unit="Nm", per_reference_torque=True),
    Signal("load_std", 32, 8, False, LOAD_STD_SCALE, unit="Nm", per_reference_torque=True),
    Signal("motor_temperature", 40, 16, True, TEMPERATURE_SCALE, unit="degC"),
    Signal("reserved2", 56, 8, role=SignalRole.RESERVED),
)
SIGNALS_BY_KIND: dict[FrameKind, tuple[Signal, ...]] = {
    FrameKind.MOTOR_STATE: MOTOR_STATE_SIGNALS,
    FrameKind.CONTROLLER_STATUS: CONTROLLER_STATUS_SIGNALS,
    FrameKind.JOINT_STATUS: JOINT_STATUS_SIGNALS,
}


@dataclass(frozen=True, slots=True)
class FrameType:
    """Catalogue entry: one CAN identifier."""

    arbitration_id: int
    data_id: int
    kind: FrameKind
    joint: int  # -1 for ControllerStatus
    name: str
    counter_modulus: int


def _build_catalogue() -> dict[int, FrameType]:
    catalogue = {
        CONTROLLER_STATUS_ID: FrameType(
            CONTROLLER_STATUS_ID, CONTROLLER_STATUS_DATA_ID, FrameKind.CONTROLLER_STATUS, -1,
            "ControllerStatus", STATUS_COUNTER_MODULUS)
    }
    for joint in range(MAX_JOINTS):
        catalogue[MOTOR_STATE_BASE_ID + joint] = FrameType(
            MOTOR_STATE_BASE_ID + joint, MOTOR_STATE_DATA_ID_BASE + joint, FrameKind.MOTOR_STATE,
            joint, f"MotorState_{joint}", MOTOR_COUNTER_MODULUS)
        catalogue[JOINT_STATUS_BASE_ID + joint] = FrameType(
            JOINT_STATUS_BASE_ID + joint, JOINT_STATUS_DATA_ID_BASE + joint, FrameKind.JOINT_STATUS,
            joint, f"JointStatus_{joint}", STATUS_COUNTER_MODULUS)
    return dict(sorted(catalogue.items()))


CATALOGUE: dict[int, FrameType] = _build_catalogue()
"""arbitration ID -> FrameType for every frame of docs/PROTOCOL.md."""


def _id_register(data_id: int) -> int:
    """CRC register after feeding the data ID (low byte, high byte), before the final XOR."""
    return crc8h2f(bytes((data_id & 0xFF, data_id >> 8))) ^ FINAL_XOR


_KIND_ERROR, _KIND_MOTOR, _KIND_CONTROLLER, _KIND_JOINT = (int(k) for k in FrameKind)
_ERR_NONE, _ERR_UNKNOWN_ID, _ERR_WRONG_DLC, _ERR_CRC, _ERR_BAD_VALUE = (int(k) for k in DecodeErrorKind)
_MAX_MODE = int(max(Mode))
# Lookup tables over the 11-bit ID space, used by the block decoder.
_ID_SPACE = 1 << 11
_KIND_BY_ID = np.zeros(_ID_SPACE, dtype=np.int8)
_JOINT_BY_ID = np.full(_ID_SPACE, -1, dtype=np.int8)
_ID_REGISTER_BY_ID = np.zeros(_ID_SPACE, dtype=np.uint8)
for _frame in CATALOGUE.values():
    _KIND_BY_ID[_frame.arbitration_id] = _frame.kind
    _JOINT_BY_ID[_frame.arbitration_id] = _frame.joint
    _ID_REGISTER_BY_ID[_frame.arbitration_id] = _id_register(_frame.data_id)
_ID_REGISTER: dict[int, int] = {f.arbitration_id: _id_register(f.data_id) for f in CATALOGUE.values()}


# ----------------------------------------------------------------------------------------------
# Frame records


@dataclass(slots=True)
class MotorState:
    """One controller tick of one joint. tick: alive counter = controller tick mod 256."""

    joint: int
    tick: int
    torque: float  # fraction of max. joint torque
    speed: float  # rad/s, motor side
    position: float  # rad, motor angle modulo one revolution

    @property
    def arbitration_id(self) -> int:
        return MOTOR_STATE_BASE_ID + self.joint


@dataclass(slots=True)
class ControllerStatus:
    """Controller status (lower rate): alive counter, mode, test-cycle number, segment, tick."""

    counter: int
    mode: Mode
    cycle: int
    segment: int
    tick: int  # controller tick mod 2**24

    @property
    def arbitration_id(self) -> int:
        return CONTROLLER_STATUS_ID


@dataclass(slots=True)
class JointStatus:
    """Per-joint status: controller's load-torque estimate (fraction) and motor temperature (degC)."""

    joint: int
    counter: int
    load_estimate: float
    load_std: float
    motor_temperature: float

    @property
    def arbitration_id(self) -> int:
        return JOINT_STATUS_BASE_ID + self.joint


@dataclass(slots=True)
class DecodeError:
    """A frame that could not be decoded; ``kind`` says why, ``detail`` in words."""

    kind: DecodeErrorKind
    arbitration_id: int
    detail: str = ""


Frame = MotorState | ControllerStatus | JointStatus


# ----------------------------------------------------------------------------------------------
# Scalar encoding


def _quantise(name: str, value: float, scale: float, raw_min: int, raw_max: int) -> int:
    """Physical value -> raw integer, rounded to nearest (ties to even) and saturated."""
    value = float(value)
    if math.isnan(value):
        raise FrameValueError(f"{name}: NaN cannot be encoded; pass a finite number")
    steps = value / scale
    if steps >= raw_max:
        return raw_max
    if steps <= raw_min:
        return raw_min
    return min(max(round(steps), raw_min), raw_max)


def _quantise_position(value: float) -> int:
    value = float(value)
    if not math.isfinite(value):
        raise FrameValueError(f"position: {value} cannot be encoded; pass a finite angle in rad")
    return round(math.fmod(value, 2.0 * math.pi) / POSITION_SCALE) % 16384


def _check_joint(joint: int) -> int:
    if isinstance(joint, bool) or not isinstance(joint, (int, np.integer)) or not 0 <= joint < MAX_JOINTS:
        raise FrameValueError(f"joint: {joint!r} is not a joint index; use 0 .. {MAX_JOINTS - 1}")
    return int(joint)


def _check_unsigned(name: str, value: int, limit: int) -> int:
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or not 0 <= value < limit:
        raise FrameValueError(f"{name}: {value!r} out of range; use an integer 0 .. {limit - 1}")
    return int(value)


def _check_counter(name: str, value: int) -> int:
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < 0:
        raise FrameValueError(f"{name}: {value!r} must be a non-negative integer (it is sent modulo its width)")
    return int(value)


def frame_crc(arbitration_id: int, data: bytes | bytearray) -> int:
    """E2E CRC a frame of this catalogue ID must carry in byte 0: CRC-8H2F over the data ID
    (low, high byte) and ``data[1:8]``.  Raises KeyError for IDs outside the catalogue."""
    return crc8h2f(bytes(data[1:FRAME_LENGTH]), init=_ID_REGISTER[arbitration_id])


def frame_crc_block(ids: np.ndarray, data: np.ndarray) -> np.ndarray:
    """Vectorised :func:`frame_crc`: the byte-0 CRC of each row of ``data`` (uint8[n, 8]) for its
    catalogue ID in ``ids`` (every ID must be in the catalogue)."""
    return crc8h2f_block(np.asarray(data)[:, 1:], init=_ID_REGISTER_BY_ID[np.asarray(ids, dtype=np.int64)])


def _protect(arbitration_id: int, word: int) -> bytes:
    """Put the CRC into byte 0 of the 64-bit word and return the 8 frame bytes."""
    payload = (word & ~0xFF).to_bytes(8, "little")
    crc = crc8h2f(payload[1:], init=_ID_REGISTER[arbitration_id])
    return bytes((crc,)) + payload[1:]


def _pack_signed(raw: int, start: int, length: int) -> int:
    return (raw & ((1 << length) - 1)) << start


def encode_motor_state(joint: int, tick: int, torque: float, speed: float, position: float) -> bytes:
    """Protected MotorState_j payload (8 bytes). tick: controller tick (sent mod 256)."""
    joint = _check_joint(joint)
    tick = _check_counter("tick", tick) & 0xFF
    word = (
        (tick << 8)
        | _pack_signed(_quantise("torque", torque, TORQUE_SCALE, -(1 << 15), (1 << 15) - 1), 16, 16)
        | _pack_signed(_quantise("speed", speed, SPEED_SCALE, -(1 << 17), (1 << 17) - 1), 32, 18)
        | (_quantise_position(position) << 50)
    )
    return _protect(MOTOR_STATE_BASE_ID + joint, word)


def encode_controller_status(counter: int, mode: int, cycle: int, segment: int, tick: int) -> bytes:
    """Protected ControllerStatus payload. counter sent mod 16, cycle mod 2**16, tick mod 2**24."""
    counter = _check_counter("counter", counter) & 0xF
    try:
        mode = Mode(mode)
    except ValueError:
        raise FrameValueError(f"mode: {mode!r} is not a controller mode; use one of {[m.name for m in Mode]}") from None
    cycle = _check_counter("cycle", cycle) % CYCLE_MODULUS
    segment = _check_unsigned("segment", segment, 256)
    tick = _check_counter("tick", tick) % STATUS_TICK_MODULUS
    word = (counter << 8) | (int(mode) << 12) | (cycle << 16) | (segment << 32) | (tick << 40)
    return _protect(CONTROLLER_STATUS_ID, word)


def encode_joint_status(
    joint: int, counter: int, load_estimate: float, load_std: float, motor_temperature: float
) -> bytes:
    """Protected JointStatus_j payload. load_* as fraction of max. torque, temperature in degC."""
    joint = _check_joint(joint)
    counter = _check_counter("counter", counter) & 0xF
    word = (
        (counter << 8)
        | _pack_signed(_quantise("load_estimate", load_estimate, TORQUE_SCALE, -(1 << 15), (1 << 15) - 1), 16, 16)
        | (_quantise("load_std", load_std, LOAD_STD_SCALE, 0, 255) << 32)
        | _pack_signed(_quantise("motor_temperature", motor_temperature, TEMPERATURE_SCALE,
                                 -(1 << 15), (1 << 15) - 1), 40, 16)
    )
    return _protect(JOINT_STATUS_BASE_ID + joint, word)


def encode(frame: Frame) -> tuple[int, bytes]:
    """(arbitration_id, protected payload) for a frame record."""
    if isinstance(frame, MotorState):
        return frame.arbitration_id, encode_motor_state(
            frame.joint, frame.tick, frame.torque, frame.speed, frame.position)
    if isinstance(frame, ControllerStatus):
        return CONTROLLER_STATUS_ID, encode_controller_status(
            frame.counter, frame.mode, frame.cycle, frame.segment, frame.tick)
    if isinstance(frame, JointStatus):
        return frame.arbitration_id, encode_joint_status(
            frame.joint, frame.counter, frame.load_estimate, frame.load_std, frame.motor_temperature)
    raise FrameValueError(f"frame: {type(frame).__name__} is not a catalogue frame record")


def to_message(arbitration_id: int, data: bytes | Sequence[int], timestamp: float = 0.0) -> can.Message:
    """A classical CAN message with an 11-bit identifier (is_extended_id=False), DLC 8."""
    return can.Message(
        timestamp=timestamp, arbitration_id=arbitration_id, is_extended_id=False,
        dlc=len(data), data=data, check=False,
    )


# ----------------------------------------------------------------------------------------------
# Block encoding (vectorised)


def _quantise_block(name: str, values: np.ndarray, scale: float, raw_min: int, raw_max: int) -> np.ndarray:
    values = np.asarray(values, dtype=np.float64)
    if np.isnan(values).any():
        raise FrameValueError(f"{name}: contains NaN at index {int(np.flatnonzero(np.isnan(values))[0])}; "
                              "pass finite numbers")
    with np.errstate(over="ignore"):  # |value| near float max: inf is clipped like any overflow
        steps = values / scale
    return np.rint(np.clip(steps, raw_min, raw_max)).astype(np.int64)


def encode_motor_state_block(
    joint: int | np.ndarray, ticks: np.ndarray, torque: np.ndarray, speed: np.ndarray, position: np.ndarray
) -> np.ndarray:
    """Protected MotorState payloads for n samples -> uint8[n, 8] (row i = frame of sample i).

    ``joint`` is one joint index or an int array broadcastable to n; ticks are controller ticks
    (sent mod 256); torque (fraction), speed (rad/s), position (rad) are float arrays.
    """
    ticks = np.asarray(ticks)
    n = ticks.shape[0] if ticks.ndim else 1
    joints = np.broadcast_to(np.asarray(joint), (n,))
    if joints.size and (not np.issubdtype(joints.dtype, np.integer) or joints.min() < 0 or joints.max() >= MAX_JOINTS):
        raise FrameValueError(f"joint: must be integers 0 .. {MAX_JOINTS - 1}")
    if not np.issubdtype(ticks.dtype, np.integer):
        raise FrameValueError("ticks: must be an integer array of controller ticks")
    position = np.asarray(position, dtype=np.float64)
    if not np.isfinite(position).all():
        raise FrameValueError("position: contains a non-finite angle; pass finite angles in rad")
    torque_raw = _quantise_block("torque", torque, TORQUE_SCALE, -(1 << 15), (1 << 15) - 1)
    speed_raw = _quantise_block("speed", speed, SPEED_SCALE, -(1 << 17), (1 << 17) - 1)
    position_raw = np.rint(np.fmod(position, 2.0 * math.pi) / POSITION_SCALE).astype(np.int64) % 16384
    word = (
        ((ticks.astype(np.int64) & 0xFF) << 8)
        | ((torque_raw & 0xFFFF) << 16)
        | ((speed_raw & 0x3FFFF) << 32)
    ).astype("<u8") | (position_raw.astype("<u8") << np.uint64(50))
    rows = np.ascontiguousarray(word.reshape(n)).view(np.uint8).reshape(n, 8)
    rows[:, 0] = frame_crc_block(MOTOR_STATE_BASE_ID + joints.astype(np.int64), rows)
    return rows


def _integer_block(name: str, values, n: int, limit: int | None = None) -> np.ndarray:
    array = np.broadcast_to(np.asarray(values), (n,))
    if array.size and (not np.issubdtype(array.dtype, np.integer) or array.min() < 0
                       or (limit is not None and array.max() >= limit)):
        bound = f"0 .. {limit - 1}" if limit is not None else ">= 0"
        raise FrameValueError(f"{name}: must be integers {bound}")
    return array.astype(np.int64)


def _protect_block(words: np.ndarray, ids: np.ndarray) -> np.ndarray:
    rows = np.ascontiguousarray(words.astype("<u8")).view(np.uint8).reshape(-1, 8)
    rows[:, 0] = frame_crc_block(ids, rows)
    return rows


def encode_controller_status_block(counter, mode, cycle, segment, tick) -> np.ndarray:
    """Protected ControllerStatus payloads for n frames -> uint8[n, 8] (same rules as the scalar
    encoder: counter mod 16, cycle mod 2**16, tick mod 2**24; mode a Mode value, segment 0..255)."""
    n = int(np.broadcast(np.asarray(counter), np.asarray(mode), np.asarray(cycle), np.asarray(segment),
                         np.asarray(tick)).size)
    mode = _integer_block("mode", mode, n, _MAX_MODE + 1)
    words = ((_integer_block("counter", counter, n) & 0xF) << 8) | (mode << 12) \
        | ((_integer_block("cycle", cycle, n) % CYCLE_MODULUS) << 16) \
        | (_integer_block("segment", segment, n, 256) << 32) \
        | ((_integer_block("tick", tick, n) % STATUS_TICK_MODULUS) << 40)
    return _protect_block(words, np.full(n, CONTROLLER_STATUS_ID))


def encode_joint_status_block(joint, counter, load_estimate, load_std, motor_temperature) -> np.ndarray:
    """Protected JointStatus payloads for n frames -> uint8[n, 8] (saturating like the scalar encoder)."""
    n = int(np.broadcast(np.asarray(joint), np.asarray(counter), np.asarray(load_estimate),
                         np.asarray(load_std), np.asarray(motor_temperature)).size)
    joints = _integer_block("joint", joint, n, MAX_JOINTS)
    words = ((_integer_block("counter", counter, n) & 0xF) << 8) \
        | ((np.broadcast_to(_quantise_block("load_estimate", load_estimate, TORQUE_SCALE, -(1 << 15), (1 << 15) - 1),
                            (n,)) & 0xFFFF) << 16) \
        | (np.broadcast_to(_quantise_block("load_std", load_std, LOAD_STD_SCALE, 0, 255), (n,)) << 32) \
        | ((np.broadcast_to(_quantise_block("motor_temperature", motor_temperature, TEMPERATURE_SCALE,
                                            -(1 << 15), (1 << 15) - 1), (n,)) & 0xFFFF) << 40)
    return _protect_block(words, JOINT_STATUS_BASE_ID + joints)


# ----------------------------------------------------------------------------------------------
# Scalar decoding (never raises)


def _signed(raw: int, length: int) -> int:
    half = 1 << (length - 1)
    return (raw ^ half) - half


def decode(arbitration_id: int, data: bytes | bytearray | Sequence[int]) -> Frame | DecodeError:
    """Decode one frame; any ID, any bytes, any length -> a frame record or a DecodeError."""
    try:
        arbitration_id = int(arbitration_id)
        frame_type = CATALOGUE.get(arbitration_id)
    except (TypeError, ValueError, OverflowError):
        return DecodeError(DecodeErrorKind.UNKNOWN_ID, -1, f"arbitration id {arbitration_id!r} is not an integer")
    if frame_type is None:
        return DecodeError(DecodeErrorKind.UNKNOWN_ID, arbitration_id, f"0x{arbitration_id:X} is not in the catalogue")
    try:
        payload = bytes(data)
    except (TypeError, ValueError, OverflowError):
        return DecodeError(DecodeErrorKind.WRONG_DLC, arbitration_id, "data is not a byte sequence")
    if len(payload) != FRAME_LENGTH:
        return DecodeError(DecodeErrorKind.WRONG_DLC, arbitration_id, f"{len(payload)} data bytes, expected 8")
    expected = crc8h2f(payload[1:], init=_ID_REGISTER[arbitration_id])
    if expected != payload[0]:
        return DecodeError(DecodeErrorKind.CRC, arbitration_id,
                           f"crc 0x{payload[0]:02X}, expected 0x{expected:02X}")
    word = int.from_bytes(payload, "little")
    if frame_type.kind is FrameKind.MOTOR_STATE:
        return MotorState(
            joint=frame_type.joint,
            tick=(word >> 8) & 0xFF,
            torque=_signed((word >> 16) & 0xFFFF, 16) * TORQUE_SCALE,
            speed=_signed((word >> 32) & 0x3FFFF, 18) * SPEED_SCALE,
            position=(word >> 50) * POSITION_SCALE,
        )
    if frame_type.kind is FrameKind.CONTROLLER_STATUS:
        mode = (word >> 12) & 0xF
        if mode > max(Mode):
            return DecodeError(DecodeErrorKind.BAD_VALUE, arbitration_id, f"mode {mode} is not defined")
        return ControllerStatus(
            counter=(word >> 8) & 0xF, mode=Mode(mode), cycle=(word >> 16) & 0xFFFF,
            segment=(word >> 32) & 0xFF, tick=word >> 40,
        )
    return JointStatus(
        joint=frame_type.joint,
        counter=(word >> 8) & 0xF,
        load_estimate=_signed((word >> 16) & 0xFFFF, 16) * TORQUE_SCALE,
        load_std=((word >> 32) & 0xFF) * LOAD_STD_SCALE,
        motor_temperature=_signed((word >> 40) & 0xFFFF, 16) * TEMPERATURE_SCALE,
    )


def decode_message(message: can.Message) -> Frame | DecodeError:
    """Decode a python-can message; extended, remote and error frames are UNKNOWN_ID."""
    try:
        if message.is_extended_id or message.is_remote_frame or message.is_error_frame:
            return DecodeError(DecodeErrorKind.UNKNOWN_ID, int(message.arbitration_id),
                               "extended, remote or error frame")
        return decode(message.arbitration_id, message.data)
    except Exception as error:  # noqa: BLE001 - a decoder must never raise into the receive loop
        return DecodeError(DecodeErrorKind.UNKNOWN_ID, -1, f"not a CAN message: {error}")


# ----------------------------------------------------------------------------------------------
# Block decoding (vectorised)


@dataclass(slots=True)
class DecodedBlock:
    """Column-wise decode of n frames. Fields not defined for a row's kind hold NaN / -1.

    ``counter`` is the alive counter (MotorState: tick mod 256; status frames: 0..15) and -1 for
    rows that failed decoding; ``valid`` = (error == NONE).
    """

    arbitration_id: np.ndarray  # int64
    kind: np.ndarray  # int8 FrameKind
    error: np.ndarray  # int8 DecodeErrorKind
    crc_ok: np.ndarray  # bool (False also when the ID or DLC is wrong)
    joint: np.ndarray  # int8, -1 for ControllerStatus / errors
    counter: np.ndarray  # int16
    torque: np.ndarray  # float64, fraction
    speed: np.ndarray  # float64, rad/s
    position: np.ndarray  # float64, rad
    mode: np.ndarray  # int8
    cycle: np.ndarray  # int32
    segment: np.ndarray  # int16
    status_tick: np.ndarray  # int32, ControllerStatus.tick
    load_estimate: np.ndarray  # float64, fraction
    load_std: np.ndarray  # float64, fraction
    motor_temperature: np.ndarray  # float64, degC

    def __len__(self) -> int:
        return int(self.kind.shape[0])

    @property
    def valid(self) -> np.ndarray:
        return self.error == DecodeErrorKind.NONE

    def error_counts(self) -> dict[str, int]:
        """Number of rows per DecodeErrorKind name (NONE excluded)."""
        counts = np.bincount(self.error.astype(np.int64), minlength=len(DecodeErrorKind))
        return {kind.name: int(counts[kind]) for kind in DecodeErrorKind if kind != DecodeErrorKind.NONE}


def _field(words: np.ndarray, start: int, length: int, signed: bool = False) -> np.ndarray:
    raw = ((words >> np.uint64(start)) & np.uint64((1 << length) - 1)).astype(np.int64)
    if signed:
        half = 1 << (length - 1)
        raw = (raw ^ half) - half
    return raw


def decode_block(ids: np.ndarray, data: np.ndarray, dlc: np.ndarray) -> DecodedBlock:
    """Decode n frames at once: ids int[n], data uint8[n, 8] (zero-padded), dlc int[n]."""
    ids = np.asarray(ids, dtype=np.int64).reshape(-1)
    n = ids.shape[0]
    data = np.ascontiguousarray(data, dtype=np.uint8).reshape(n, FRAME_LENGTH)
    dlc = np.asarray(dlc).reshape(n)
    in_space = (ids >= 0) & (ids < _ID_SPACE)
    lookup = np.where(in_space, ids, 0)
    kind = np.where(in_space, _KIND_BY_ID[lookup], _KIND_ERROR).astype(np.int8)
    crc = crc8h2f_block(data[:, 1:], init=_ID_REGISTER_BY_ID[lookup])
    known = kind != _KIND_ERROR
    length_ok = dlc == FRAME_LENGTH
    crc_ok = known & length_ok & (crc == data[:, 0])
    words = data.view("<u8").reshape(n)

    error = np.full(n, _ERR_NONE, dtype=np.int8)
    error[~crc_ok] = _ERR_CRC
    error[~length_ok] = _ERR_WRONG_DLC
    error[~known] = _ERR_UNKNOWN_ID

    joint = np.full(n, -1, dtype=np.int8)
    counter = np.full(n, -1, dtype=np.int16)
    nan = np.full(n, np.nan)
    torque, speed, position = nan.copy(), nan.copy(), nan.copy()
    load_estimate, load_std, motor_temperature = nan.copy(), nan.copy(), nan
    mode = np.full(n, -1, dtype=np.int8)
    cycle = np.full(n, -1, dtype=np.int32)
    segment = np.full(n, -1, dtype=np.int16)
    status_tick = np.full(n, -1, dtype=np.int32)

    motor = np.flatnonzero(crc_ok & (kind == _KIND_MOTOR))
    if motor.size:
        w = words[motor]
        joint[motor] = _JOINT_BY_ID[ids[motor]]
        counter[motor] = _field(w, 8, 8)
        torque[motor] = _field(w, 16, 16, True) * TORQUE_SCALE
        speed[motor] = _field(w, 32, 18, True) * SPEED_SCALE
        position[motor] = _field(w, 50, 14) * POSITION_SCALE
    status = np.flatnonzero(crc_ok & (kind == _KIND_CONTROLLER))
    if status.size:
        w = words[status]
        status_mode = _field(w, 12, 4)
        bad = status[status_mode > _MAX_MODE]
        error[bad] = _ERR_BAD_VALUE
        good = status_mode <= _MAX_MODE
        status, w = status[good], w[good]
        counter[status] = _field(w, 8, 4)
        mode[status] = status_mode[good]
        cycle[status] = _field(w, 16, 16)
        segment[status] = _field(w, 32, 8)
        status_tick[status] = _field(w, 40, 24)
    joint_status = np.flatnonzero(crc_ok & (kind == _KIND_JOINT))
    if joint_status.size:
        w = words[joint_status]
        joint[joint_status] = _JOINT_BY_ID[ids[joint_status]]
        counter[joint_status] = _field(w, 8, 4)
        load_estimate[joint_status] = _field(w, 16, 16, True) * TORQUE_SCALE
        load_std[joint_status] = _field(w, 32, 8) * LOAD_STD_SCALE
        motor_temperature[joint_status] = _field(w, 40, 16, True) * TEMPERATURE_SCALE
    kind[error != _ERR_NONE] = _KIND_ERROR
    return DecodedBlock(ids, kind, error, crc_ok, joint, counter, torque, speed, position, mode, cycle,
                        segment, status_tick, load_estimate, load_std, motor_temperature)


# ----------------------------------------------------------------------------------------------
# python-can messages <-> arrays

CAN_EFF_FLAG = 0x8000_0000  # marks extended / remote / error frames in the id column (never in catalogue)
_get_id = attrgetter("arbitration_id")
_get_data = attrgetter("data")
_get_timestamp = attrgetter("timestamp")
_get_flags = attrgetter("is_extended_id", "is_remote_frame", "is_error_frame")
_is_extended = attrgetter("is_extended_id")
_is_remote = attrgetter("is_remote_frame")
_is_error = attrgetter("is_error_frame")


def messages_to_arrays(
    messages: Sequence[can.Message] | Iterable[can.Message],
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """(ids int64[n], data uint8[n, 8] zero-padded, dlc int64[n], timestamps float64[n]).

    The dlc column is the actual data length.  Extended, remote and error frames get
    ``CAN_EFF_FLAG`` or'ed into their id so that ``decode_block`` reports them as UNKNOWN_ID.
    """
    messages = messages if isinstance(messages, (list, tuple)) else list(messages)
    n = len(messages)
    payloads = list(map(_get_data, messages))
    dlc = np.fromiter(map(len, payloads), dtype=np.int64, count=n)
    if n and dlc.min() == FRAME_LENGTH and dlc.max() == FRAME_LENGTH:
        raw = b"".join(payloads)
    else:
        raw = b"".join(bytes(p[:FRAME_LENGTH]).ljust(FRAME_LENGTH, b"\0") for p in payloads)
    data = np.frombuffer(raw, dtype=np.uint8).reshape(n, FRAME_LENGTH).copy()
    ids = np.fromiter(map(_get_id, messages), dtype=np.int64, count=n)
    timestamps = np.fromiter(map(_get_timestamp, messages), dtype=np.float64, count=n)
    if any(map(_is_extended, messages)) or any(map(_is_remote, messages)) or any(map(_is_error, messages)):
        flagged = [i for i, flags in enumerate(map(_get_flags, messages)) if any(flags)]
        ids[flagged] |= CAN_EFF_FLAG
    return ids, data, dlc, timestamps
