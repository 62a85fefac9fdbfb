"""Vectorised encoders and decoders of whole blocks of frames (numpy), and python-can messages ↔ arrays.

Same layout and rules as the scalar codecs of :mod:`protocol.frames` (docs/PROTOCOL.md); these are
what the simulator and the agent use on their hot paths.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from operator import attrgetter
from typing import Iterable, Sequence

import can
import numpy as np

from protocol.catalogue import (  # noqa: F401  (lookup tables and codes shared with the scalar codecs)
    _ERR_BAD_VALUE,
    _ERR_CRC,
    _ERR_NONE,
    _ERR_UNKNOWN_ID,
    _ERR_WRONG_DLC,
    _ID_REGISTER_BY_ID,
    _ID_SPACE,
    _JOINT_BY_ID,
    _KIND_BY_ID,
    _KIND_CONTROLLER,
    _KIND_ERROR,
    _KIND_JOINT,
    _KIND_MOTOR,
    _MAX_MODE,
    CONTROLLER_STATUS_ID,
    CYCLE_MODULUS,
    FRAME_LENGTH,
    JOINT_STATUS_BASE_ID,
    LOAD_STD_SCALE,
    MAX_JOINTS,
    MOTOR_STATE_BASE_ID,
    POSITION_SCALE,
    SPEED_SCALE,
    STATUS_TICK_MODULUS,
    TEMPERATURE_SCALE,
    TORQUE_SCALE,
    DecodeErrorKind,
    FrameKind,
    FrameValueError,
    Mode,
)
from protocol.crc import crc8h2f_block


def frame_crc_block(ids: np.ndarray, data: np.ndarray) -> np.ndarray:
    """Vectorised :func:`frame_crc`: the byte-0 CRC of each row of ``data`` (uint8[n, 8]) for its
    catalogue ID in ``ids`` (every ID must be in the catalogue)."""
    return crc8h2f_block(np.asarray(data)[:, 1:], init=_ID_REGISTER_BY_ID[np.asarray(ids, dtype=np.int64)])


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
