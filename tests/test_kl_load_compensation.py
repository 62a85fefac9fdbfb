"""The KL distances do not move with the load torque (docs/KL_DETECTOR.md, "Load compensation"):
simulated cycles learned at |τl| ~ U(0.3, 0.7), evaluated at U(0.3, 0.7) and at U(0.9, 1.0); both
sides: compensated, the high load gives the KL values of the learned range; uncompensated, it does not.
Temperature fixed (45 °C) and one joint without individual variation, so the load is the only change."""

from __future__ import annotations

import math

import numpy as np
import pytest

from edge_monitor.features.base import CycleInput
from edge_monitor.features.kl_monitor import KLConfig, KLMonitor
from edge_monitor.features.segmentation import PlateauConfig
from edge_monitor.pipeline.cycle_assembly import CycleAssembler
from joint_model import DEFAULT_PARAMS
from sim_controller.config import SimConfig
from sim_controller.cycle_mode import CycleSignals, cycle_signals

LEARN, EACH = 6, 10


def _cycles(load_range: tuple[float, float], seed: int, n: int) -> list[CycleSignals]:
    config = SimConfig(joints=1, cycles=n, seed=seed, load_range=load_range, temperature_range=(45.0, 45.0))
    return list(cycle_signals(config))


def _inputs(cycles: list[CycleSignals], first: int) -> list[tuple[CycleSignals, CycleInput]]:
    """Each cycle with the CycleInput the agent's assembler gives it (measured load torque included)."""
    out = []
    for k, signals in enumerate(cycles):
        joint = signals.joints[0]
        governing = np.clip(np.searchsorted(signals.status_ticks, signals.ticks, side="left") - 1, 0, None)
        assembler = CycleAssembler(0, PlateauConfig(), 500.0)
        assembler.update(signals.ticks, joint.speed, joint.torque, signals.status_segments[governing])
        assembler.add_status(joint.load_estimate, joint.load_std, joint.motor_temperature)
        out.append((signals, assembler.end_cycle(first + k)))
    return out


@pytest.fixture(scope="module")
def data() -> dict[str, list[tuple[CycleSignals, CycleInput]]]:
    return {"learn": _inputs(_cycles((0.3, 0.7), 11, LEARN + EACH), 0),
            "high": _inputs(_cycles((0.9, 1.0), 12, EACH), LEARN + EACH)}


def _log_kl(mode: str, data: dict[str, list[tuple[CycleSignals, CycleInput]]]) -> dict[str, np.ndarray]:
    monitor = KLMonitor(KLConfig(n_nominal_cycles=LEARN, load_compensation=mode, temperature_compensation=False),
                        DEFAULT_PARAMS)
    values: dict[str, list[float]] = {"learned": [], "high": []}
    for part, name in (("learn", "learned"), ("high", "high")):
        for signals, cycle in data[part]:
            joint = signals.joints[0]
            governing = np.clip(np.searchsorted(signals.status_ticks, signals.ticks, side="left") - 1, 0, None)
            monitor.update_samples(joint.torque, joint.speed, signals.status_segments[governing])
            out = monitor.update(cycle, {})
            if math.isfinite(out.values["kl_raw"]):
                values[name].append(out.values["kl_raw"])
    return {k: np.log(v) for k, v in values.items()}


@pytest.mark.slow
@pytest.mark.parametrize("mode", ["measured", "estimate"])
def test_a_load_outside_the_learned_range_gives_the_learned_kl_values(mode: str, data) -> None:
    logs = _log_kl(mode, data)
    assert logs["learned"].size == EACH and logs["high"].size == EACH
    spread = logs["learned"].std(ddof=1)
    # two means of 10 values from the same distribution differ by < 3 standard errors (√(2/10) σ)
    assert abs(logs["high"].mean() - logs["learned"].mean()) < 3 * math.sqrt(2 / EACH) * spread


@pytest.mark.slow
def test_without_compensation_the_high_load_moves_the_kl_values(data) -> None:
    logs = _log_kl("off", data)
    spread = logs["learned"].std(ddof=1)
    assert logs["high"].mean() - logs["learned"].mean() > 3 * math.sqrt(2 / EACH) * spread


def test_the_measured_load_is_the_torque_carried_at_the_test_angle(data) -> None:
    """The plateaus measure the load to the torque noise; the controller's estimate has σl = 0.1."""
    measured = np.array([c.friction.load_torque - s.truth[0]["load"] for s, c in data["high"]])
    estimated = np.array([c.load_mean - s.truth[0]["load"] for s, c in data["high"]])
    assert np.abs(measured).max() < 2e-3
    assert np.sqrt(np.mean(estimated ** 2)) > 0.03     # rms of 10 N(0, 0.1²) errors: P(< 0.03) < 1e-4
