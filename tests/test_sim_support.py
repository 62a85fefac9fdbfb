"""Helpers shared by the simulator tests (decode a simulated frame stream into per-joint signals), and
their own test."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import can
import numpy as np

from protocol import frames as pf
from sim_controller.faults import FrameBlock


@dataclass
class JointSignals:
    tick: np.ndarray      # unwrapped controller tick (from the frame order)
    torque: np.ndarray
    speed: np.ndarray


def run_on_virtual_bus(config: Any, channel: str, **run_kwargs: Any) -> tuple[Any, int]:
    """``sim_controller.output.run`` onto a python-can virtual bus: (its summary, frames received)."""
    from sim_controller.output import run

    receiver = can.Bus(interface="virtual", channel=channel, ignore_config=True)
    try:
        summary = run(config, f"virtual:{channel}", **run_kwargs)
        received = 0
        while receiver.recv(timeout=0) is not None:
            received += 1
    finally:
        receiver.shutdown()
    return summary, received


def collect(blocks) -> FrameBlock:
    return FrameBlock.concat(list(blocks))


def decode(block: FrameBlock) -> pf.DecodedBlock:
    return pf.decode_block(block.ids, block.data, np.full(len(block), 8))


def joint_signals(decoded: pf.DecodedBlock, joint: int) -> JointSignals:
    """MotorState samples of one joint in stream order (fault-free stream: one per tick)."""
    rows = np.flatnonzero(decoded.valid & (decoded.kind == pf.FrameKind.MOTOR_STATE) & (decoded.joint == joint))
    counter = decoded.counter[rows].astype(np.int64)
    tick = np.concatenate([[0], np.cumsum(np.mod(np.diff(counter), 256))])
    return JointSignals(tick=tick, torque=decoded.torque[rows], speed=decoded.speed[rows])


def plateau_means(sig: JointSignals, speed: float, rate: float, settle_s: float = 0.25, guard_s: float = 0.02,
                  tol: float = 0.15, min_s: float = 0.3) -> list[tuple[float, int, int]]:
    """(mean torque, samples, start tick) of every run at ``speed`` (signed); the first ``settle_s`` and
    the last ``guard_s`` are discarded (the deceleration torque starts while the speed is still in the band)."""
    inside = np.abs(sig.speed - speed) < tol
    edges = np.flatnonzero(np.diff(np.concatenate([[0], inside.astype(np.int8), [0]])))
    out = []
    for start, stop in zip(edges[::2], edges[1::2]):
        first = start + int(round(settle_s * rate))
        stop = stop - int(round(guard_s * rate))
        if stop - first >= int(min_s * rate):
            out.append((float(sig.torque[first:stop].mean()), int(stop - first), int(sig.tick[start])))
    return out


def test_plateau_means_discards_settle_time_and_short_runs():
    rate = 100.0
    speed = np.concatenate([np.zeros(10), np.full(80, 5.0), np.zeros(10), np.full(20, 5.0)])
    torque = np.concatenate([np.zeros(10), np.full(25, 9.0), np.full(55, 1.0), np.zeros(30)])
    sig = JointSignals(tick=np.arange(speed.size), torque=torque, speed=speed)
    # first run: 80 samples, 25 + 5 discarded, 50 left at torque 1; second run is shorter than min_s
    assert plateau_means(sig, 5.0, rate, settle_s=0.25, guard_s=0.05, min_s=0.3) == [(1.0, 50, 10)]
