"""A fleet of simulated robots through the agent, as a user meets it: each robot is one seed of the simulator
(its defaults, or a scenario's plant timeline; wear ramps on some joints) run through the agent at its shipped
defaults (or with overrides) on the cycle-level fast path (the per-cycle quantities equal those of
``sim-controller record`` + ``edge-monitor replay``; tests/test_fast_path.py) — :func:`run_robot` — or, from the
per-cycle quantities :mod:`studies.series` keeps, only its detectors (:func:`run_robot_series`: the same
inputs, minutes instead of an hour). Both return the same run record; :mod:`studies.tally` pools them. The
command line is tools/studies/healthy_fleet_study.py.
"""

from __future__ import annotations

import logging
import math
import time
from dataclasses import dataclass
from typing import Any, Iterator

from edge_monitor.config import config_from_mapping
from edge_monitor.offline.fast_path import run_cycles
from edge_monitor.pipeline.agent import Agent
from edge_monitor.pipeline.coverage import Coverage
from sim_controller.config import SimConfig
from sim_controller.cycle_mode import CycleSignals, cycle_signals, without_motor_temperature
from sim_controller.scenario import scenario_config
from studies.bank_replay import new_bank, replay_bank
from studies.series import robot_series
from studies.settings import Overrides, settings_from
from studies.tally import DecisionTally

log = logging.getLogger(__name__)
#: Cycles per robot without ``cycles`` or a scenario that says.
DEFAULT_CYCLES = 200


@dataclass(frozen=True)
class RunSpec:
    """One simulated robot: seed, length [cycles] (None: the scenario's), joints, wear ramps, agent
    overrides (TOML tables), simulator scenario (file or packaged name)."""

    seed: int
    cycles: int | None
    joints: int = 6
    wear_ramps: tuple[str, ...] = ()
    overrides: Overrides = ()
    progress: int = 50
    scenario: str | None = None
    motor_temperature: bool = True      # False: the controller sends none (every status frame's is removed)

    def sim_config(self) -> SimConfig:
        return scenario_config(self.scenario, {"seed": self.seed, "joints": self.joints, "cycles": self.cycles},
                               fallback={"cycles": DEFAULT_CYCLES}, wear_ramps=self.wear_ramps)


def run_robot(spec: RunSpec) -> dict[str, Any]:
    """Simulate one robot through the agent; per joint the monitored cycles and alarms per quantity."""
    sim = spec.sim_config()
    agent = Agent(config_from_mapping(settings_from(spec.overrides)))
    alarms: list[dict[str, Any]] = []
    wear_truth: dict[tuple[int, int], float] = {}
    temperatures: list[float] = []
    started = time.monotonic()

    def cycles() -> Iterator[CycleSignals]:
        """The simulated cycles, their ground truth kept on the way, a status line now and then."""
        for signals in cycle_signals(sim):
            for truth in signals.truth:
                wear_truth[(int(truth["joint"]), int(truth["cycle"]))] = float(truth["wear"])
                temperatures.append(float(truth["temperature"]))
            if spec.progress and signals.cycle % spec.progress == 0 and signals.cycle:
                log.info("seed %d: cycle %d/%d, %d alarms, %.0f s", spec.seed, signals.cycle, sim.cycles,
                         len(agent.stats.alarms), time.monotonic() - started)
            yield signals if spec.motor_temperature else without_motor_temperature(signals)

    tally = DecisionTally()
    stages: dict[tuple[int, int, str], str | None] = {}
    for symptom in run_cycles(agent, cycles()):
        tally.add(symptom.joint, symptom.cycle, symptom.decisions)
        stages.update({(symptom.joint, symptom.cycle, a.quantity):
                       (symptom.decisions[a.quantity].calibration or {}).get("stage") for a in symptom.alarms})
    for alarm in agent.stats.alarms:
        joint, cycle = int(alarm["joint"]), int(alarm["cycle"])
        alarms.append({"joint": joint, "cycle": cycle, "quantity": alarm["quantity"],
                       "wear": wear_truth.get((joint, cycle), math.nan),
                       "stage": stages.get((joint, cycle, alarm["quantity"]))})
    worn = sorted({j for (j, _), w in wear_truth.items() if w > 0})
    return {"seed": spec.seed, "alarms": alarms, "worn": worn, **tally.fields(worn),
            "wear_truth": {str(j): [wear_truth[(j, c)] for c in range(sim.cycles) if (j, c) in wear_truth]
                           for j in worn},
            "temperature": [min(temperatures), max(temperatures)], "seconds": time.monotonic() - started,
            "coverage": {str(j): m.coverage_summary() for j, m in agent.joints.items()},
            "advisories": agent.stats.advisories}


def pauses(sim: SimConfig) -> dict[int, float]:
    """The seconds the simulated robot stands still before a cycle (its timeline's stops)."""
    return {event.cycle: 3600.0 * event.stop_hours for event in sim.timeline if event.stop_hours}


def kept_robot_pauses(seed: int, cycles: int, scenario: str | None) -> dict[int, float]:
    """:func:`pauses` of the robot :func:`~studies.series.robot_series` keeps for ``seed``, ``cycles`` and
    ``scenario`` (its 6 joints; a scenario's timeline does not depend on them)."""
    return pauses(scenario_config(scenario, {"seed": seed, "joints": 6, "cycles": cycles}))


def run_robot_series(spec: RunSpec) -> dict[str, Any]:
    """:func:`run_robot` from the per-cycle quantities :mod:`studies.series` keeps (computed once per code
    version): only the detectors run, the agent's own :class:`DetectorBank` at the same settings fed what
    the fast path fed it (the detector inputs and the cycle's motor temperature, or on a robot without one the
    lubricant temperature read from the friction). One difference: the
    series begin once the KL distances have values, ≈ 10 cycles after the wear score, so the wear
    detector's warm-up nominal is learned from later cycles than the agent's (tests/
    test_fleet_study_from_series.py). Wear must come from the scenario file (``--wear-ramp`` changes the
    simulation, not the kept series)."""
    started = time.monotonic()
    sim = spec.sim_config()
    decision = config_from_mapping(settings_from(spec.overrides)).decision
    series = robot_series(spec.seed, sim.cycles, sim.joints, spec.scenario, spec.motor_temperature)
    tally = DecisionTally()
    alarms: list[dict[str, Any]] = []
    wear_truth: dict[int, list[float]] = {}
    coverage: dict[str, Any] = {}
    for joint, rows in series.items():
        truth = wear_truth.setdefault(joint, [float(rows[0]["wear"])] * sim.cycles if rows else [])
        bank, tested = new_bank(decision), Coverage(decision.quantities)
        for step in replay_bank(bank, rows, joint, "robot", pauses=pauses(sim)):
            truth[step.cycle] = float(step.row["wear"])
            tally.add(joint, step.cycle, step.decisions)
            tested.update(bank.reasons)
            alarms += [{"joint": joint, "cycle": step.cycle, "quantity": a.quantity, "wear": float(step.row["wear"]),
                        "stage": (step.decisions[a.quantity].calibration or {}).get("stage")} for a in step.raised]
        coverage[str(joint)] = tested.summary()
    worn = sorted(j for j, w in wear_truth.items() if w and max(w) > 0)
    return {"seed": spec.seed, "alarms": alarms, "worn": worn, **tally.fields(worn),
            "wear_truth": {str(j): wear_truth[j] for j in worn}, "seconds": time.monotonic() - started,
            "coverage": coverage}
