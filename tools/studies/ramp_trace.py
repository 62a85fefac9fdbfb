#!/usr/bin/env python3
"""One worn joint's detectors, cycle by cycle, on the same robot with and without motor temperature: why one
finds a wear ramp later than the other (docs/WITHOUT_MOTOR_TEMPERATURE.md, "Not met").

Per robot the per-cycle series studies.series keeps for the scenario (computed if missing, ≈ 4 min a robot and
kind), replayed through the agent's detectors at the shipped settings (studies.bank_replay, as
watching_study.py --from-series does). Printed per block of ``--every`` cycles from ``--start`` to ``--stop``:
the true wear, the temperature the detectors follow (the motor temperature, or the lubricant temperature read
from the friction) and the simulator's true lubricant temperature, the wear score (raw and in its nominal's standard units) and each detector's statistic over
its threshold; then each kind's first alarm.

Usage: ``python tools/studies/ramp_trace.py --scenario studies/scenarios/medium_ramp.toml --seed 7306 --joint 1``
"""

from __future__ import annotations

import argparse
import math
import sys
from pathlib import Path
from typing import Any

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))

from edge_monitor.pipeline.decision_config import DecisionConfig  # noqa: E402
from studies.bank_replay import detectors_temperature, new_bank, replay_bank, standard_units  # noqa: E402
from studies.series import robot_series  # noqa: E402


def trace(rows: list[dict[str, Any]], joint: int) -> tuple[list[dict[str, Any]], int | None]:
    """Per cycle: the row's wear, the detectors' temperature, the wear score raw and standardised, and per
    detector (statistic, threshold); and the first cycle any detector alarmed (None: none)."""
    bank, out, first = new_bank(DecisionConfig()), [], None
    for step in replay_bank(bank, rows, joint=joint):
        score = step.row.get("wear_score")
        wear_detector = bank.detectors["wear"]
        standard = standard_units(wear_detector, score) if score is not None and wear_detector.density else math.nan
        out.append({"cycle": step.cycle, "wear": step.row.get("wear"), "temperature": detectors_temperature(step.row)[0],
                    "lubricant": step.row.get("temperature"),
                    "score": score, "z": standard,
                    "tests": {q: (d.statistic, d.threshold) for q, d in step.decisions.items()}})
        if step.raised and first is None:
            first = step.cycle
    return out, first


def block_line(block: list[dict[str, Any]]) -> str:
    """One line for a block of cycles: means of wear, temperature, score and z; the last statistics."""
    def mean(key: str) -> float:
        values = [r[key] for r in block if r[key] is not None and not math.isnan(r[key])]
        return float(np.mean(values)) if values else math.nan
    last = block[-1]["tests"]
    tests = "  ".join(f"{q} {s:6.2f}/{h:5.2f}" if s is not None and h is not None else f"{q} –"
                      for q, (s, h) in last.items())
    return (f"{block[0]['cycle']:4d}–{block[-1]['cycle']:<4d} wear {mean('wear'):5.1f}  T {mean('temperature'):5.1f} "
            f"(lubricant {mean('lubricant'):5.1f})  "
            f"score {mean('score'):6.2f}  z {mean('z'):5.2f}  {tests}")


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--scenario", required=True, help="simulator scenario TOML (it sets the wear)")
    parser.add_argument("--seed", type=int, required=True)
    parser.add_argument("--joint", type=int, default=1)
    parser.add_argument("--cycles", type=int, default=400)
    parser.add_argument("--start", type=int, default=80)
    parser.add_argument("--stop", type=int, default=200)
    parser.add_argument("--every", type=int, default=10)
    args = parser.parse_args(argv)
    for motor_temperature in (True, False):
        rows = robot_series(args.seed, args.cycles, 6, args.scenario, motor_temperature=motor_temperature)[args.joint]
        traced, first = trace(rows, args.joint)
        print(f"seed {args.seed} joint {args.joint}, {'with' if motor_temperature else 'without'} motor temperature "
              f"(T: {'motor' if motor_temperature else 'read from the friction'})")
        window = [r for r in traced if args.start <= r["cycle"] <= args.stop]
        for i in range(0, len(window), args.every):
            print("  " + block_line(window[i:i + args.every]))
        wear = next((r["wear"] for r in traced if r["cycle"] == first), None)
        print(f"  first alarm: cycle {first}" + ("" if wear is None else f" (true wear {wear:.1f})") + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
