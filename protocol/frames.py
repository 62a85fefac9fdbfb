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
from typing import Sequence

import can
import numpy as np

from protocol import catalogue
from protocol.catalogue import (  # the catalogue's public names are part of this module's interface  # noqa: F401
    _ID_REGISTER,
    _MAX_MODE,
    CATALOGUE,
    CONTROLLER_STATUS_DATA_ID,
    CONTROLLER_STATUS_ID,
    CONTROLLER_STATUS_SIGNALS,
    CYCLE_MODULUS,
    FRAME_LENGTH,
    JOINT_STATUS_BASE_ID,
    JOINT_STATUS_DATA_ID_BASE,
    JOINT_STATUS_SIGNALS,
    LOAD_STD_SCALE,
    MAX_JOINTS,
    MAX_SPEED_LEVELS,
    MOTOR_COUNTER_MODULUS,
    MOTOR_STATE_BASE_ID,
    MOTOR_STATE_DATA_ID_BASE,
    MOTOR_STATE_SIGNALS,
    POSITION_SCALE,
    SEGMENT_NONE,
    SEGMENT_PRODUCTION,
    SIGNALS_BY_KIND,
    SPEED_SCALE,
    STATUS_COUNTER_MODULUS,
    STATUS_TICK_MODULUS,
    TEMPERATURE_SCALE,
    TORQUE_SCALE,
    DecodeErrorKind,
    FrameKind,
    FrameType,
    FrameValueError,
    Mode,
    Signal,
    SignalRole,
)
from protocol.crc import crc8h2f

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

from protocol.frame_blocks import (  # noqa: E402  (the vectorised codecs are part of this module's interface)
    DecodedBlock,
    decode_block,
    encode_controller_status_block,
    encode_joint_status_block,
    encode_motor_state_block,
    frame_crc_block,
    messages_to_arrays,
)

__all__ = [*catalogue.__all__,
           "ControllerStatus",
           "DecodeError",
           "DecodedBlock",
           "Frame",
           "JointStatus",
           "MotorState",
           "decode",
           "decode_block",
           "decode_message",
           "encode",
           "encode_controller_status",
           "encode_controller_status_block",
           "encode_joint_status",
           "encode_joint_status_block",
           "encode_motor_state",
           "encode_motor_state_block",
           "frame_crc",
           "frame_crc_block",
           "messages_to_arrays",
           "to_message",
           ]
