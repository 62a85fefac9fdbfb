"""Vectorised encoders for the status frames (ControllerStatus, JointStatus), docs/PROTOCOL.md.

``protocol.frames`` has a block encoder for MotorState only; the simulator sends ~350 status frames
per simulated second, and encoding them one by one cost more than the joint physics. These
encoders build the same 64-bit words in numpy and protect them with ``crc8h2f_block``;
tests/test_sim_frames.py checks them byte for byte against the scalar ``protocol.frames`` encoders.
(Candidate to move into ``protocol.frames``.)
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray

from protocol import frames as pf
from protocol.crc import crc8h2f, crc8h2f_block


def _register(data_id: int) -> int:
    return crc8h2f(bytes((data_id & 0xFF, data_id >> 8))) ^ 0xFF


def _quantise(values: ArrayLike, scale: float, raw_min: int, raw_max: int) -> NDArray[np.int64]:
    return np.rint(np.clip(np.asarray(values, dtype=np.float64) / scale, raw_min, raw_max)).astype(np.int64)


def _protect(words: NDArray[np.int64], data_id: int) -> NDArray[np.uint8]:
    rows = np.ascontiguousarray(words.astype("<u8")).view(np.uint8).reshape(-1, 8).copy()
    rows[:, 0] = crc8h2f_block(rows[:, 1:], init=_register(data_id))
    return rows


def encode_controller_status_block(counter: ArrayLike, mode: ArrayLike, cycle: ArrayLike, segment: ArrayLike,
                                   tick: ArrayLike) -> NDArray[np.uint8]:
    """ControllerStatus payloads (uint8[n, 8]); counter mod 16, cycle mod 2¹⁶, tick mod 2²⁴."""
    counter, mode, cycle, segment, tick = np.broadcast_arrays(*(np.asarray(a, dtype=np.int64)
                                                                for a in (counter, mode, cycle, segment, tick)))
    words = ((counter & 0xF) << 8) | ((mode & 0xF) << 12) | ((cycle % pf.CYCLE_MODULUS) << 16) \
        | ((segment & 0xFF) << 32) | ((tick % pf.STATUS_TICK_MODULUS) << 40)
    return _protect(words.reshape(-1), pf.CONTROLLER_STATUS_DATA_ID)


def encode_joint_status_block(joint: int, counter: ArrayLike, load_estimate: ArrayLike, load_std: ArrayLike,
                              motor_temperature: ArrayLike) -> NDArray[np.uint8]:
    """JointStatus_j payloads (uint8[n, 8]); load in torque fractions, temperature in °C."""
    counter = np.asarray(counter, dtype=np.int64)
    load = _quantise(load_estimate, pf.TORQUE_SCALE, -(1 << 15), (1 << 15) - 1)
    std = _quantise(load_std, pf.LOAD_STD_SCALE, 0, 255)
    temp = _quantise(motor_temperature, pf.TEMPERATURE_SCALE, -(1 << 15), (1 << 15) - 1)
    counter, load, std, temp = np.broadcast_arrays(counter, load, std, temp)
    words = ((counter & 0xF) << 8) | ((load & 0xFFFF) << 16) | ((std & 0xFF) << 32) | ((temp & 0xFFFF) << 40)
    return _protect(words.reshape(-1), pf.JOINT_STATUS_DATA_ID_BASE + joint)
