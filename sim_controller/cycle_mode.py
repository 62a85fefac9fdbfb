"""Cycle-level mode of the simulator: each cycle's joint signals as the frames would carry them,
without encoding frames (for statistical studies that need 10⁵ cycles).

The physics is the frame mode's own (:meth:`Controller.simulated_cycles`, same seeds, same random
streams); values are quantised exactly as the wire quantises them (torque, speed, load estimate,
its std and the motor temperature), so a consumer that labels samples as the agent's ingest does
gets the same per-cycle quantities as from the frames. The plant timeline (load range, ambient,
payload error, σl, stops) is the frame mode's too. Link faults are not applied in this mode.
Ticks are the controller's, not wrapped: the wire carries them mod 2²⁴ (status) and mod 2⁸ (samples).
Units: speed rad/s, torque a fraction of the joint's maximum torque, temperature °C, time in ticks.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import Any, Iterator

import numpy as np
from numpy.typing import NDArray

from protocol import frames as pf
from sim_controller.config import SimConfig
from sim_controller.controller import STATUS_EVERY, Controller, SimulatedCycle


def _wire(values: NDArray[np.float64], scale: float, raw_min: int, raw_max: int) -> NDArray[np.float64]:
    """``values`` after encoding and decoding: saturated to the field and rounded to its step."""
    return np.rint(np.clip(np.asarray(values, dtype=float) / scale, raw_min, raw_max)) * scale


@dataclass(frozen=True)
class JointSignals:
    """One joint's samples of one cycle (every controller tick) and its status-frame values."""

    joint: int
    torque: NDArray[np.float64]
    speed: NDArray[np.float64]
    load_estimate: NDArray[np.float64]          # per status frame
    load_std: NDArray[np.float64]               # per status frame
    motor_temperature: NDArray[np.float64]      # per status frame [°C]


@dataclass(frozen=True)
class CycleSignals:
    """One cycle: controller ticks of the samples, ticks and segment codes of the status frames
    (sent every ``STATUS_EVERY`` ticks, after that tick's joint samples), every joint's signals, and
    the ground truth of the cycle (one record per joint: its plant conditions and any stop before it
    included)."""

    cycle: int
    ticks: NDArray[np.int64]
    status_ticks: NDArray[np.int64]
    status_segments: NDArray[np.int64]
    joints: list[JointSignals]
    truth: list[dict[str, Any]]


def without_motor_temperature(signals: CycleSignals) -> CycleSignals:
    """The cycle as a controller that sends no motor temperature sends it (every status value NaN)."""
    joints = [replace(j, motor_temperature=np.full_like(j.motor_temperature, np.nan)) for j in signals.joints]
    return replace(signals, joints=joints)


def _signals(sc: SimulatedCycle) -> CycleSignals:
    status = sc.ticks % STATUS_EVERY == 0
    torque_limit = 1 << 15
    joints = []
    for j in range(sc.sim["torque"].shape[0]):
        joints.append(JointSignals(
            joint=j,
            torque=_wire(sc.sim["torque"][j], pf.TORQUE_SCALE, -torque_limit, torque_limit - 1),
            speed=_wire(sc.sim["speed"][j], pf.SPEED_SCALE, -(1 << 17), (1 << 17) - 1),
            load_estimate=_wire(sc.sim["load_estimate"][j, status], pf.TORQUE_SCALE, -torque_limit, torque_limit - 1),
            load_std=_wire(np.full(int(status.sum()), sc.cond.plant.load_std), pf.LOAD_STD_SCALE, 0, 255),
            motor_temperature=_wire(sc.cond.motor_temperature[j] + sc.status_noise[j], pf.TEMPERATURE_SCALE,
                                    -torque_limit, torque_limit - 1)))
    return CycleSignals(cycle=sc.cycle, ticks=sc.ticks, status_ticks=sc.ticks[status],
                        status_segments=sc.ref.segment[status].astype(np.int64), joints=joints, truth=[])


def cycle_signals(config: SimConfig) -> Iterator[CycleSignals]:
    """Every cycle of the run described by ``config`` (with its ground truth), no frames."""
    controller = Controller(config)
    for sc in controller.simulated_cycles():
        signals = _signals(sc)
        signals.truth.extend(controller.drain_truth())
        controller.ticks_done += sc.ref.n
        controller.cycles_done += 1
        yield signals
