#!/usr/bin/env python3
"""A healthy robot whose controller sends no motor temperature (docs/WITHOUT_MOTOR_TEMPERATURE.md):
detector-cycles monitored per stage, threshold crossings and held detector-cycles.

Each seed is the simulator's default 6-joint robot on the cycle-level fast path, with every motor
temperature of its status frames removed (``--with-temperature`` keeps them: the same robot through our
frames). Every alarm is acknowledged at once, as an operator would, so a lasting shift alarms again and each
crossing is counted. ``--no-friction-temperature`` runs the agent as it was before the detectors followed
the friction's temperature (no settling, no holds).

Usage: ``python tools/studies/no_temperature_study.py --seeds 601 602 --cycles 1100 [--budget-period week]
[--with-temperature | --no-friction-temperature] [--json OUT]``; one status line every 200 cycles.
"""

from __future__ import annotations

import argparse
import json
import logging
import sys
from collections import Counter
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT))

from edge_monitor.config import config_from_mapping  # noqa: E402
from edge_monitor.offline.fast_path import CycleFeeder  # noqa: E402
from edge_monitor.pipeline.agent import Agent  # noqa: E402
from edge_monitor.pipeline.joint_monitor import JointMonitor  # noqa: E402
from edge_monitor.pipeline.nominal_temperature import MOTOR_TEMPERATURE  # noqa: E402
from edge_monitor.records import Symptom  # noqa: E402
from sim_controller.config import SimConfig  # noqa: E402
from sim_controller.cycle_mode import CycleSignals, cycle_signals  # noqa: E402

log = logging.getLogger("no_temperature_study")


def without_temperature(signals: CycleSignals) -> CycleSignals:
    """The cycle as a controller without a motor temperature sends it."""
    joints = [replace(j, motor_temperature=np.full_like(j.motor_temperature, np.nan)) for j in signals.joints]
    return replace(signals, joints=joints)


def run_robot(seed: int, cycles: int, budget_period: str, keep_temperature: bool) -> dict[str, Any]:
    """One robot: monitored detector-cycles per stage, crossings (joint, cycle, quantity, stage), held
    detector-cycles per joint."""
    agent = Agent(config_from_mapping({"decision": {"budget_period": budget_period}}))
    feeder = CycleFeeder(agent)
    monitored: Counter[str] = Counter()
    crossings: list[dict[str, Any]] = []

    def take(symptoms: list[Symptom]) -> None:
        for symptom in symptoms:
            for quantity, decision in symptom.decisions.items():
                stage = agent.joints[symptom.joint].detectors.detectors[quantity].stage
                if decision.state == "monitoring" and decision.threshold is not None \
                        and not decision.reason.startswith("held"):
                    monitored[stage] += 1
                if decision.alarm:
                    crossings.append({"joint": symptom.joint, "cycle": symptom.cycle, "quantity": quantity,
                                      "stage": stage})
                    agent.acknowledge(symptom.joint, [quantity])

    for k, signals in enumerate(cycle_signals(SimConfig(joints=6, cycles=cycles, seed=seed))):
        take(feeder.update(signals if keep_temperature else without_temperature(signals)))
        if k % 200 == 0:
            log.info("seed %d: cycle %d of %d, %d crossings", seed, k, cycles, len(crossings))
    take(feeder.finish())
    return {"seed": seed, "arl0": agent.config.decision.arl0, "monitored": dict(monitored), "crossings": crossings,
            "held": {str(j): sum(m.detectors.held.values()) for j, m in agent.joints.items()}}


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--seeds", type=int, nargs="+", default=[601])
    p.add_argument("--cycles", type=int, default=1100)
    p.add_argument("--budget-period", default="week", help="the false-alarm budget's period (one per robot and …)")
    arm = p.add_mutually_exclusive_group()
    arm.add_argument("--with-temperature", action="store_true", help="keep the motor temperatures")
    arm.add_argument("--no-friction-temperature", action="store_true",
                     help="the agent before it followed the friction's temperature")
    p.add_argument("--json", help="write the results here")
    args = p.parse_args()
    logging.basicConfig(level=logging.INFO, format="%(message)s")
    logging.getLogger("edge_monitor").setLevel(logging.ERROR)
    if args.no_friction_temperature:
        # the counterfactual: a joint without a motor temperature gives its detectors none (no settling, no holds)
        JointMonitor.joint_temperature = lambda self, cycle, values: (None, MOTOR_TEMPERATURE)  # type: ignore[method-assign]
    results = [run_robot(seed, args.cycles, args.budget_period, args.with_temperature) for seed in args.seeds]
    for r in results:
        stages = Counter(c["stage"] for c in r["crossings"])
        due = sum(r["monitored"].values()) / r["arl0"]
        print(f"seed {r['seed']}: monitored {r['monitored']}, crossings {dict(stages) or 0} "
              f"({due:.2f} due), held {sum(r['held'].values())}")
    if args.json:
        Path(args.json).write_text(json.dumps(results, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
