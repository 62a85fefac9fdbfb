"""The frame catalogue: identifiers, E2E data IDs, scaling, enums and signal layouts (docs/PROTOCOL.md).

One source of truth for the wire format: the encoders and decoders (:mod:`protocol.frames`,
:mod:`protocol.frame_blocks`) and the DBC (:mod:`protocol.dbc`) are derived from it.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from enum import IntEnum

import numpy as np

from protocol.crc import FINAL_XOR, crc8h2f

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

__all__ = [
    "CATALOGUE",
    "CONTROLLER_STATUS_DATA_ID",
    "CONTROLLER_STATUS_ID",
    "CONTROLLER_STATUS_SIGNALS",
    "CYCLE_MODULUS",
    "DecodeErrorKind",
    "FRAME_LENGTH",
    "FrameKind",
    "FrameType",
    "FrameValueError",
    "JOINT_STATUS_BASE_ID",
    "JOINT_STATUS_DATA_ID_BASE",
    "JOINT_STATUS_SIGNALS",
    "LOAD_STD_SCALE",
    "MAX_JOINTS",
    "MAX_SPEED_LEVELS",
    "MOTOR_COUNTER_MODULUS",
    "MOTOR_STATE_BASE_ID",
    "MOTOR_STATE_DATA_ID_BASE",
    "MOTOR_STATE_SIGNALS",
    "Mode",
    "POSITION_SCALE",
    "SEGMENT_NONE",
    "SEGMENT_PRODUCTION",
    "SIGNALS_BY_KIND",
    "SPEED_SCALE",
    "STATUS_COUNTER_MODULUS",
    "STATUS_TICK_MODULUS",
    "Signal",
    "SignalRole",
    "TEMPERATURE_SCALE",
    "TORQUE_SCALE",
]
