#!/usr/bin/env python3
"""False alarms of the agent on a healthy robot at the simulator's defaults, and detection of a wear
ramp: the product's promise measured as a user meets it (docs/DETECTION.md, "Healthy robot").

Each seed is one robot: the simulator's defaults (6 joints, ±8 % individual friction variation, the
lubricant warming from 30 °C by the thermal model, load spread 0.3 … 0.7 per cycle), run through the
agent at its shipped defaults on the cycle-level fast path (the per-cycle quantities equal those of
``sim-controller record`` + ``edge-monitor replay``; tests/test_fast_path.py). ``--wear-ramp`` adds
wear on some joints (``JOINT:START:END:FROM:TO``, as ``sim-controller record --wear-ramp``).
``--scenario FILE|NAME`` runs every robot in a simulator scenario instead of the defaults (its plant
timeline: load steps, stops, a plant week; ``sim-controller``'s packaged ``load_step``,
``mild_load_step``, ``plant_week`` by name; each seed replaces the file's, ``--cycles`` and
``--joints`` override it when given).

Reported per quantity: monitored cycles of healthy joints (the exposure), false alarms (alarms on
joints without wear), the run length to false alarm it implies (a lower bound when there are none),
and per worn joint the cycle of its first alarm and the wear then; with worn joints, per quantity the
fraction of them not alarmed yet next to the mean miss probability the detectors reported (Pm against
observed misses). Seeds run in parallel worker
processes (``--jobs``); a status line per seed and every ``--progress`` cycles.

``--from-series`` runs only the detectors over the per-cycle quantities tools/studies/fleet_series.py keeps
(the same inputs; minutes instead of an hour once the series are kept).

Usage: ``python tools/studies/healthy_fleet_study.py --cycles 200 --seeds 1 2 [--wear-ramp 2:100:200:0:60]
[--scenario load_step] [--set decision.allowance=0] [--from-series] [--json OUT]``.
"""

from __future__ import annotations

import argparse
import json
import logging
import math
import os
import sys
import time
from concurrent.futures import ProcessPoolExecutor
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Iterator

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")     # before numpy loads: tiny matrices, a threaded BLAS only spins

from edge_monitor.config import config_from_mapping  # noqa: E402
from edge_monitor.offline.fast_path import run_cycles  # noqa: E402
from edge_monitor.pipeline.agent import Agent  # noqa: E402
from sim_controller.config import SimConfig  # noqa: E402
from sim_controller.cycle_mode import CycleSignals, cycle_signals  # noqa: E402
from sim_controller.scenario import scenario_config  # noqa: E402

log = logging.getLogger("healthy_fleet_study")
#: Cycles per robot without ``--cycles`` or a scenario that says.
DEFAULT_CYCLES = 200


@dataclass(frozen=True)
class RunSpec:
    """One simulated robot: seed, length [cycles] (None: the scenario's), joints, wear ramps, agent
    overrides (TOML tables), simulator scenario (file or packaged name)."""

    seed: int
    cycles: int | None
    joints: int = 6
    wear_ramps: tuple[str, ...] = ()
    overrides: tuple[tuple[str, Any], ...] = ()
    progress: int = 50
    scenario: str | None = None

    def sim_config(self) -> SimConfig:
        return scenario_config(self.scenario, {"seed": self.seed, "joints": self.joints, "cycles": self.cycles},
                               fallback={"cycles": DEFAULT_CYCLES}, wear_ramps=self.wear_ramps)


def settings_from(overrides: tuple[tuple[str, Any], ...]) -> dict[str, Any]:
    doc: dict[str, Any] = {}
    for dotted, value in overrides:
        table, _, key = dotted.rpartition(".")
        node = doc
        for part in filter(None, table.split(".")):
            node = node.setdefault(part, {})
        node[key] = value
    return doc


@dataclass
class DecisionTally:
    """What a study keeps of the decisions, per joint and quantity: the monitored cycles, the first cycle
    of the steady stage and the reported miss probability per cycle (until the alarm)."""

    monitored: dict[int, dict[str, int]] = field(default_factory=dict)
    monitored_steady: dict[int, dict[str, int]] = field(default_factory=dict)
    steady_from: dict[int, dict[str, int]] = field(default_factory=dict)
    miss: dict[int, dict[str, dict[int, float]]] = field(default_factory=dict)

    def add(self, joint: int, cycle: int, decisions: dict[str, Any]) -> None:
        for q, decision in decisions.items():
            steady = (decision.calibration or {}).get("stage") == "steady"
            if steady:
                self.steady_from.setdefault(joint, {}).setdefault(q, cycle)
            if decision.state == "monitoring" and decision.threshold is not None and decision.statistic is not None:
                for tally in (self.monitored, self.monitored_steady) if steady else (self.monitored,):
                    counts = tally.setdefault(joint, {})
                    counts[q] = counts.get(q, 0) + 1
                if decision.miss_probability is not None and not decision.alarm:
                    self.miss.setdefault(joint, {}).setdefault(q, {})[cycle] = decision.miss_probability

    def fields(self, worn: list[int]) -> dict[str, Any]:
        """The run record's ``monitored``, ``steady_from`` and ``miss_probability`` (worn joints only)."""
        return {"monitored": {str(j): c for j, c in self.monitored.items()},
                "monitored_steady": {str(j): c for j, c in self.monitored_steady.items()},
                "steady_from": {str(j): c for j, c in self.steady_from.items()},
                "miss_probability": {str(j): {q: {str(c): p for c, p in per.items()}
                                              for q, per in self.miss.get(j, {}).items()} for j in worn}}


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
            yield signals

    tally = DecisionTally()
    for symptom in run_cycles(agent, cycles()):
        tally.add(symptom.joint, symptom.cycle, symptom.decisions)
    for alarm in agent.stats.alarms:
        joint, cycle = int(alarm["joint"]), int(alarm["cycle"])
        alarms.append({"joint": joint, "cycle": cycle, "quantity": alarm["quantity"],
                       "wear": wear_truth.get((joint, cycle), math.nan)})
    worn = sorted({j for (j, _), w in wear_truth.items() if w > 0})
    return {"seed": spec.seed, "alarms": alarms, "worn": worn, **tally.fields(worn),
            "wear_truth": {str(j): [wear_truth[(j, c)] for c in range(sim.cycles) if (j, c) in wear_truth]
                           for j in worn},
            "temperature": [min(temperatures), max(temperatures)], "seconds": time.monotonic() - started}


def run_robot_series(spec: RunSpec) -> dict[str, Any]:
    """:func:`run_robot` from the per-cycle quantities tools/studies/fleet_series.py keeps (computed once per code
    version): only the detectors run, the agent's own :class:`DetectorBank` at the same settings fed what
    the fast path fed it (the detector inputs and the cycle's motor temperature). One difference: the
    series begin once the KL distances have values, ≈ 10 cycles after the wear score, so the wear
    detector's warm-up nominal is learned from later cycles than the agent's (tests/
    test_fleet_study_from_series.py). Wear must come from the scenario file (``--wear-ramp`` changes the
    simulation, not the kept series)."""
    from fleet_series import robot_series

    from edge_monitor.pipeline.detectors import DetectorBank

    started = time.monotonic()
    sim = spec.sim_config()
    decision = config_from_mapping(settings_from(spec.overrides)).decision
    series = robot_series(spec.seed, sim.cycles, sim.joints, spec.scenario)
    tally = DecisionTally()
    alarms: list[dict[str, Any]] = []
    wear_truth: dict[int, list[float]] = {}
    for joint, rows in series.items():
        bank = DetectorBank(decision, {})
        truth = wear_truth.setdefault(joint, [float(rows[0]["wear"])] * sim.cycles if rows else [])
        for row in rows:
            cycle = int(row["cycle"])
            truth[cycle] = float(row["wear"])
            bank.observe_temperature(row.get("motor_temperature"))
            decisions, raised = bank.update(row, "robot", joint, cycle)
            tally.add(joint, cycle, decisions)
            alarms += [{"joint": joint, "cycle": cycle, "quantity": a.quantity, "wear": float(row["wear"]),
                        "stage": (decisions[a.quantity].calibration or {}).get("stage")} for a in raised]
    worn = sorted(j for j, w in wear_truth.items() if w and max(w) > 0)
    return {"seed": spec.seed, "alarms": alarms, "worn": worn, **tally.fields(worn),
            "wear_truth": {str(j): wear_truth[j] for j in worn}, "seconds": time.monotonic() - started}


def earliest_alarm(run: dict[str, Any], joint: int, quantity: str | None = None) -> dict[str, Any] | None:
    """The first alarm of ``joint`` in ``run`` (of ``quantity`` only, if given), or None."""
    mine = [a for a in run["alarms"] if a["joint"] == joint and quantity in (None, a["quantity"])]
    return min(mine, key=lambda a: a["cycle"]) if mine else None


def summarise(runs: list[dict[str, Any]]) -> dict[str, Any]:
    """Pooled over robots: false alarms and exposure per quantity on unworn joints, first alarms of worn ones."""
    exposure: dict[str, int] = {}
    false_alarms: dict[str, int] = {}
    steady_exposure: dict[str, int] = {}
    steady_alarms: dict[str, int] = {}
    detections = []
    for run in runs:
        worn = set(run["worn"])
        for tally, key in ((exposure, "monitored"), (steady_exposure, "monitored_steady")):
            for joint, counts in run.get(key, {}).items():
                if int(joint) in worn:
                    continue
                for q, n in counts.items():
                    tally[q] = tally.get(q, 0) + n
        for alarm in run["alarms"]:
            if alarm["joint"] in worn:
                continue
            false_alarms[alarm["quantity"]] = false_alarms.get(alarm["quantity"], 0) + 1
            if alarm.get("stage") == "steady":
                steady_alarms[alarm["quantity"]] = steady_alarms.get(alarm["quantity"], 0) + 1
        for joint in worn:
            detections.append({"seed": run["seed"], "joint": joint, "first_alarm": earliest_alarm(run, joint)})
    per_quantity = {}
    for q, n in sorted(exposure.items()):
        k = false_alarms.get(q, 0)
        # with no alarm, the 95 % one-sided Poisson bound: rate ≤ 3/exposure
        per_quantity[q] = {"exposure": n, "false_alarms": k,
                           "arl0": n / k if k else None, "arl0_95_lower": n / 3.0 if not k else None,
                           "steady_exposure": steady_exposure.get(q, 0), "steady_false_alarms": steady_alarms.get(q, 0)}
    return {"per_quantity": per_quantity, "detections": detections,
            "false_alarms": sum(false_alarms.values()), "miss_forecast": miss_forecast(runs)}


def miss_forecast(runs: list[dict[str, Any]], every: int = 5) -> dict[str, list[dict[str, float]]]:
    """Per quantity and every ``every`` cycles over the worn joints: the fraction not alarmed yet (the
    observed miss frequency) next to the mean reported miss probability (an alarmed joint counts 0),
    and the mean true wear (docs/DETECTION.md, "Miss probability against observed misses")."""
    out: dict[str, list[dict[str, float]]] = {}
    worn = [(run, j) for run in runs for j in run["worn"]]
    if not worn:
        return out
    cycles = len(next(iter(worn[0][0]["wear_truth"].values())))
    quantities = sorted({a["quantity"] for run, _ in worn for a in run["alarms"]})
    for q in quantities:
        first = [alarm["cycle"] if (alarm := earliest_alarm(run, j, q)) else math.inf for run, j in worn]
        rows = []
        for cycle in range(0, cycles, every):
            missed, reported, wear = 0, 0.0, 0.0
            for (run, j), first_alarm in zip(worn, first):
                if cycle < first_alarm:
                    missed += 1
                    reported += run["miss_probability"].get(str(j), {}).get(q, {}).get(str(cycle), 1.0)
                wear += run["wear_truth"][str(j)][cycle]
            n = len(worn)
            rows.append({"cycle": cycle, "wear": wear / n, "observed_miss": missed / n, "mean_pm": reported / n})
        out[q] = rows
    return out


def parse_set(text: str) -> tuple[str, Any]:
    key, sep, raw = text.partition("=")
    if not sep:
        raise argparse.ArgumentTypeError(f"--set expects TABLE.KEY=VALUE, got {text!r}")
    try:
        value = json.loads(raw)
    except json.JSONDecodeError:
        value = raw
    return key.strip(), value


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--cycles", type=int, default=None,
                    help=f"cycles per robot (default: the scenario's, else {DEFAULT_CYCLES})")
    ap.add_argument("--seeds", type=int, nargs="+", default=[1, 2])
    ap.add_argument("--joints", type=int, default=6)
    ap.add_argument("--wear-ramp", action="append", default=[], metavar="JOINT:START:END:FROM:TO")
    ap.add_argument("--scenario", metavar="FILE.toml|NAME",
                    help="simulator scenario for every robot (e.g. load_step, mild_load_step, plant_week)")
    ap.add_argument("--set", action="append", default=[], type=parse_set, metavar="TABLE.KEY=VALUE",
                    help="agent setting (value as JSON), e.g. decision.allowance=0")
    ap.add_argument("--from-series", action="store_true",
                    help="run only the detectors over the per-cycle quantities tools/studies/fleet_series.py keeps "
                         "(computed once per code version; wear from the scenario file only)")
    ap.add_argument("--jobs", type=int, default=2)
    ap.add_argument("--progress", type=int, default=50, help="status line every N cycles (0: off)")
    ap.add_argument("--json", type=Path, default=None)
    args = ap.parse_args(argv)
    logging.basicConfig(level=logging.INFO, format="%(asctime)s %(message)s", datefmt="%H:%M:%S")
    specs = [RunSpec(seed, args.cycles, args.joints, tuple(args.wear_ramp), tuple(args.set), args.progress,
                     args.scenario) for seed in args.seeds]
    try:
        sim = specs[0].sim_config()
    except ValueError as exc:          # SimConfigError, ScenarioError: names the field
        ap.error(str(exc))
    if args.from_series and args.wear_ramp:
        ap.error("--from-series: put the wear in the scenario file (--wear-ramp changes the simulation)")
    with ProcessPoolExecutor(max_workers=max(1, args.jobs)) as pool:
        runs = list(pool.map(run_robot_series if args.from_series else run_robot, specs))
    result = {"cycles": sim.cycles, "seeds": args.seeds, "joints": args.joints, "wear_ramps": args.wear_ramp,
              "scenario": args.scenario, "timeline": [e.to_dict() for e in sim.timeline],
              "overrides": dict(args.set), "runs": runs, "summary": summarise(runs)}
    for q, row in result["summary"]["per_quantity"].items():
        arl = f"ARL0 ≈ {row['arl0']:.0f}" if row["arl0"] else f"ARL0 ≥ {row['arl0_95_lower']:.0f} (95 %)"
        print(f"{q:12s} monitored {row['exposure']:6d} healthy joint-cycles, false alarms {row['false_alarms']:3d}, {arl}")
    for d in result["summary"]["detections"]:
        first = d["first_alarm"]
        print(f"seed {d['seed']} worn joint {d['joint']}: " + (
            f"first alarm cycle {first['cycle']} ({first['quantity']}, wear {first['wear']:.1f})" if first
            else "no alarm"))
    for q, rows in result["summary"]["miss_forecast"].items():
        shown = [r for r in rows if 0 < r["observed_miss"] < 1 or 0 < r["mean_pm"] < 0.999]
        print(f"{q:12s} miss observed / mean reported Pm: " + ", ".join(
            f"wear {r['wear']:.0f}: {r['observed_miss']:.2f}/{r['mean_pm']:.2f}" for r in shown))
    if args.json:
        args.json.write_text(json.dumps(result, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
