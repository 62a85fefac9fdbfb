"""What a false-alarm budget costs in detection: wear at the first alarm for budgets of one false alarm
per robot-day, -week, -month and -year, on a slow, a medium and a fast wear ramp and a step
(docs/DETECTION.md, "The false-alarm budget").

Each (seed, ramp) is one simulated joint at the simulator's defaults (its own friction variation, the
lubricant warming from 30 °C, load spread) through the agent at its shipped defaults on the fast path
(tests/test_fast_path.py). The detectors' statistics do not depend on the threshold, so one run serves
every budget: whenever a detector of the joint adopts a threshold (a new nominal), a copy of it is
re-derived for each budget's ARL0 on the same nominal (:meth:`SequentialDetector.retarget`), and a
budget's first alarm is the first cycle a statistic reaches that budget's threshold. Budgets are
converted at 300 cycles a day over 6 joints × 4 detectors, as the agent does by default.

The command line is tools/studies/budget_cost.py (≈ 1–2 min CPU per run here).
"""

from __future__ import annotations

import copy
import logging
import math
import time
from typing import Any, Iterator

from edge_monitor.config import config_from_mapping
from edge_monitor.offline.fast_path import run_cycles
from edge_monitor.pipeline.agent import Agent
from edge_monitor.pipeline.detectors import DecisionConfig
from edge_monitor.stats.sequential_detector import SequentialDetector
from sim_controller.cycle_mode import CycleSignals, cycle_signals
from sim_controller.scenario import scenario_config
from studies.settings import Overrides, settings_from

log = logging.getLogger(__name__)
#: name → (wear ramp JOINT:START:END:FROM:TO, cycles simulated): the ramps start once the detectors monitor.
RAMPS: dict[str, tuple[str, int]] = {"slow (0→50 over 600)": ("0:100:700:0:50", 560),
                                     "medium (0→50 over 150)": ("0:100:250:0:50", 225),
                                     "fast (0→50 over 40)": ("0:100:140:0:50", 160),
                                     "step (0→25)": ("0:100:101:0:25", 170)}
CRITICAL_WEAR = 35.0


def budgets() -> dict[str, float]:
    """Budget name → ARL0 per detector [cycles] at the agent's default split and cycle rate."""
    return {f"1 per robot-{p}": DecisionConfig(budget_period=p).arl0 for p in ("day", "week", "month", "year")}


def budget_thresholds(detector: SequentialDetector, targets: dict[str, float], cycle: int) -> dict[str, float]:
    """The threshold each budget gives on ``detector``'s current nominal."""
    out = {}
    for name, arl0 in targets.items():
        twin = copy.deepcopy(detector)
        twin.retarget(arl0)
        twin.update(math.nan, cycle)           # adopts the re-derived threshold (the value itself is skipped)
        out[name] = twin.threshold if twin.threshold is not None else math.inf
    return out


def run(seed: int, ramp: str, overrides: Overrides = ()) -> dict[str, Any]:
    """One joint with ``ramp``: per budget, the first alarm (cycle, quantity, true wear); ``overrides``:
    agent settings (TABLE.KEY, value) on top of the shipped defaults."""
    spec, cycles = RAMPS[ramp]
    sim = scenario_config(None, {"seed": seed, "joints": 1, "cycles": cycles}, fallback={}, wear_ramps=(spec,))
    agent = Agent(config_from_mapping(settings_from(overrides)))
    targets = budgets()
    wear: dict[int, float] = {}
    # quantity → (the nominal its threshold was adopted for, thresholds per budget)
    current: dict[str, tuple[tuple[str, int], dict[str, float]]] = {}
    first: dict[str, dict[str, Any]] = {}
    started = time.monotonic()

    def signals() -> Iterator[CycleSignals]:
        for s in cycle_signals(sim):
            wear.update({int(t["cycle"]): float(t["wear"]) for t in s.truth})
            yield s

    for symptom in run_cycles(agent, signals()):
        monitor = agent.joints[symptom.joint]
        for quantity, decision in symptom.decisions.items():
            detector = monitor.detectors.detectors[quantity]
            if detector.calibration is None or decision.statistic is None:
                continue
            key = (detector.stage, detector.fits)                  # which nominal the threshold is for
            if quantity not in current or current[quantity][0] != key:
                current[quantity] = (key, budget_thresholds(detector, targets, symptom.cycle))
            for name, h in current[quantity][1].items():
                if name not in first and decision.statistic >= h:
                    first[name] = {"cycle": symptom.cycle, "quantity": quantity, "wear": wear.get(symptom.cycle)}
    log.info("seed %d %s: done in %.0f s", seed, ramp, time.monotonic() - started)
    return {"seed": seed, "ramp": ramp, "first_alarm": {n: first.get(n) for n in targets}}


def cost_table(results: list[dict[str, Any]]) -> str:
    names = list(budgets())
    lines = ["| ramp | seed | " + " | ".join(f"{n} (ARL0 {budgets()[n]:.3g})" for n in names) + " |",
             "|---|---|" + "---|" * len(names)]
    for r in results:
        cells = []
        for n in names:
            a = r["first_alarm"][n]
            cells.append("—" if a is None else f"{a['wear']:.1f} ({a['quantity']}, cycle {a['cycle']})"
                         + (" **late**" if a["wear"] is not None and a["wear"] >= CRITICAL_WEAR else ""))
        lines.append(f"| {r['ramp']} | {r['seed']} | " + " | ".join(cells) + " |")
    return "\n".join(lines)
