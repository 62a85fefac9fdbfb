"""One design point through the simulator's cycle-level mode and the agent (the real per-cycle pipeline,
:mod:`edge_monitor.offline.fast_path`).

Per design point the agent sees one run of one simulated robot (the simulator's default robot of
``joints`` joints with its seeded individual variation; only the monitored joint's samples are fed):

1. **nominal cycles** at the nominal levels (fault f = −2, i.e. no wear; disturbances at 0): the
   agent learns the joint's friction model and the KL nominal density, the baselines their nominal
   models. The nominal run is the same for every design point (same seed), so every point is
   compared against the same learned nominal;
2. **test cycles** at the design point's levels: the same robot (its joints pinned to the nominal
   run's friction parameters), fresh random streams (seed derived from the point index), cycle numbers
   and controller ticks continuing those of the nominal run.

The test quantity q of a detector at the point is the mean of its per-cycle values over the test
cycles (cycles without a value are left out and counted). Units: as the detectors' own.
"""

from __future__ import annotations

import dataclasses
import logging
import time
from contextlib import contextmanager
from dataclasses import dataclass
from typing import Any, Iterator

import numpy as np

from edge_monitor.config import AgentConfig
from edge_monitor.offline.evaluation.detectors import Readout
from edge_monitor.offline.evaluation.factors import Factor, sim_settings
from edge_monitor.offline.fast_path import run_cycles
from edge_monitor.pipeline.agent import Agent
from edge_monitor.records import Symptom
from sim_controller.config import JointOverride, SimConfig
from sim_controller.controller import STATUS_EVERY, Controller
from sim_controller.cycle_mode import CycleSignals, cycle_signals

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class PointSpec:
    """One design point: index, coded levels (one per factor), and the run settings shared by all points."""

    index: int
    coded: tuple[float, ...]
    factors: tuple[Factor, ...]
    detectors: tuple[str, ...]
    agent: AgentConfig
    joint: int = 0
    joints: int = 6
    seed: int = 1
    test_cycles: int = 20

    @property
    def nominal_cycles(self) -> int:
        """Cycles the agent needs before every detector has a value: the joint model, then the KL nominal."""
        return self.agent.model.learning_cycles * int(self.agent.model.enabled) + self.agent.kl.n_nominal_cycles

    def nominal_coded(self) -> tuple[float, ...]:
        return tuple(-2.0 if f.name == self.factors[0].name else 0.0 for f in self.factors)


@dataclass
class PointResult:
    """Per detector: q (mean over the test cycles), its per-cycle std and the count of cycles with a value;
    the ground truth the simulator reports for the monitored joint (means over the test cycles)."""

    index: int
    coded: list[float]
    q: dict[str, float]
    q_std: dict[str, float]
    q_cycles: dict[str, int]
    truth: dict[str, float]
    seconds: float

    def to_dict(self) -> dict[str, Any]:
        return dataclasses.asdict(self)


def point_seed(seed: int, index: int) -> int:
    """Seed of a point's test cycles, derived from the evaluation seed and the point index."""
    return int(np.random.SeedSequence([seed, index + 1]).generate_state(1)[0])


def _only_joint(signals: CycleSignals, joint: int) -> CycleSignals:
    return dataclasses.replace(signals, joints=[j for j in signals.joints if j.joint == joint])


def _cycles(spec: PointSpec, truth: list[dict[str, Any]]) -> Iterator[CycleSignals]:
    """Nominal cycles, then test cycles renumbered to continue them (ticks aligned to the status period)."""
    factors = list(spec.factors)
    robot = SimConfig(joints=spec.joints, seed=spec.seed)
    nominal = robot.with_(cycles=spec.nominal_cycles,
                          **sim_settings(factors, spec.nominal_coded(), spec.joint, spec.joints))
    pinned = tuple(JointOverride(friction=s.friction, load_sign=s.load_sign) for s in Controller(robot).joints)
    test = robot.with_(cycles=spec.test_cycles, seed=point_seed(spec.seed, spec.index), joint_overrides=pinned,
                       **sim_settings(factors, spec.coded, spec.joint, spec.joints))
    end = 0
    for signals in cycle_signals(nominal):
        end = int(signals.ticks[-1]) + 1
        yield _only_joint(signals, spec.joint)
    offset = -(-end // STATUS_EVERY) * STATUS_EVERY
    for signals in cycle_signals(test):
        truth.extend(t for t in signals.truth if t["joint"] == spec.joint)
        yield _only_joint(dataclasses.replace(signals, cycle=signals.cycle + nominal.cycles,
                                              ticks=signals.ticks + offset,
                                              status_ticks=signals.status_ticks + offset), spec.joint)


@contextmanager
def _quiet_agent() -> Iterator[None]:
    """The agent's per-joint INFO lines (model learned, grid fixed, …) repeat for every point: held back."""
    loggers = [logging.getLogger(name) for name in ("edge_monitor.pipeline", "edge_monitor.features")]
    levels = [lg.level for lg in loggers]
    for lg in loggers:
        lg.setLevel(max(logging.WARNING, lg.getEffectiveLevel()))
    try:
        yield
    finally:
        for lg, level in zip(loggers, levels):
            lg.setLevel(level)


def run_point(spec: PointSpec) -> PointResult:
    """Simulate one design point and read every detector (see the module docstring)."""
    with _quiet_agent():
        return _run_point(spec)


def _run_point(spec: PointSpec) -> PointResult:
    started = time.monotonic()
    config = dataclasses.replace(spec.agent, decision=dataclasses.replace(spec.agent.decision, enabled=False))
    agent = Agent(config)
    truth: list[dict[str, Any]] = []
    nominal: list[Symptom] = []
    readout: Readout | None = None
    values: dict[str, list[float]] = {d: [] for d in spec.detectors}
    for symptom in run_cycles(agent, _cycles(spec, truth)):
        if symptom.joint != spec.joint:
            continue
        if symptom.cycle < spec.nominal_cycles:
            nominal.append(symptom)
            continue
        if readout is None:
            readout = Readout(spec.detectors, nominal)
        for name, v in readout.values(symptom).items():
            values[name].append(v)
    q, q_std, q_cycles = {}, {}, {}
    for name, vs in values.items():
        arr = np.asarray(vs, dtype=float)
        ok = arr[np.isfinite(arr)]
        q[name] = float(ok.mean()) if ok.size else float("nan")
        q_std[name] = float(ok.std(ddof=1)) if ok.size > 1 else float("nan")
        q_cycles[name] = int(ok.size)
    keys = ("temperature", "load", "load_estimate", "wear", "p2p_delay")
    means = {k: float(np.mean([t[k] for t in truth])) for k in keys} if truth else {}
    return PointResult(index=spec.index, coded=list(spec.coded), q=q, q_std=q_std, q_cycles=q_cycles,
                       truth=means, seconds=time.monotonic() - started)
