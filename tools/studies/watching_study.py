#!/usr/bin/env python3
"""Always watching (docs/DETECTION.md, "Coverage" and "Watching while the joint warms"): robots through the whole
agent on the cycle-level fast path, at its shipped defaults, with or without motor temperature, on the
simulator's defaults or a scenario (a plant week), optionally with wear ramps. Per joint and detector the share
of the cycles it tested after its first learning (coverage) and why not otherwise; the first alarm of each worn
joint (cycle, detector, stage, true wear); the false alarms of the unworn joints per stage against those due at
the stated run length.

Usage: ``python tools/studies/watching_study.py --seeds 7101-7104 [--cycles 1000] [--scenario plant_week]
[--no-motor-temperature] [--wear-ramp 2:300:450:0:50 ...] [--set decision.budget_period=week] [--from-series]
[--jobs 2] [--json OUT]``; one status line per robot every 200 cycles. ``--from-series`` runs only the detectors
over kept per-cycle quantities (studies/series.py), for many robots or many settings.
"""

from __future__ import annotations

import os

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")     # tiny matrices: threaded BLAS only spins

import argparse  # noqa: E402
import json  # noqa: E402
import logging  # noqa: E402
import sys  # noqa: E402
from concurrent.futures import ProcessPoolExecutor  # noqa: E402
from pathlib import Path  # noqa: E402
from typing import Any  # noqa: E402

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT))

from edge_monitor.config import config_from_mapping  # noqa: E402
from studies.robots import RunSpec, run_robot, run_robot_series  # noqa: E402
from studies.settings import parse_seeds, parse_set, settings_from  # noqa: E402
from studies.statistics import poisson_interval  # noqa: E402
from studies.tally import earliest_alarm  # noqa: E402

DISTRIBUTION = ("kl_raw", "kl_weighted", "joint")


def coverage_rows(run: dict[str, Any]) -> list[dict[str, Any]]:
    """Per joint: each detector's share tested, the best distribution detector's, and the untested reasons."""
    rows = []
    for joint, per in sorted(run["coverage"].items(), key=lambda kv: int(kv[0])):
        shares = {q: c["share"] for q, c in per.items()}
        best = max((shares.get(q) or 0.0 for q in DISTRIBUTION), default=0.0)
        reasons: dict[str, int] = {}
        for c in per.values():
            for reason, n in c["not_tested"].items():
                reasons[reason] = reasons.get(reason, 0) + n
        rows.append({"seed": run["seed"], "joint": int(joint), "shares": shares, "distribution": best,
                     "not_tested": reasons})
    return rows


def alarm_stage(run: dict[str, Any], alarm: dict[str, Any]) -> str:
    """The stage an alarm was raised in: the one its decision states, else (a decision without calibration, e.g.
    the joint vector's) the joint's: steady from the cycle its detector's steady stage began."""
    if alarm.get("stage") in ("warm-up", "steady"):
        return str(alarm["stage"])
    start = (run.get("steady_from") or {}).get(str(alarm["joint"]), {}).get(alarm["quantity"])
    return "steady" if isinstance(start, int) and alarm["cycle"] >= start else "warm-up"


def false_alarms(runs: list[dict[str, Any]], arl0: float) -> dict[str, dict[str, float]]:
    """Per stage: false alarms of unworn joints, their tested detector-cycles, and those due at ``arl0``."""
    out: dict[str, dict[str, float]] = {stage: {"alarms": 0, "cycles": 0} for stage in ("warm-up", "steady")}
    for run in runs:
        worn = set(run["worn"])
        for joint, counts in run["monitored"].items():
            if int(joint) in worn:
                continue
            steady = sum(run["monitored_steady"].get(joint, {}).values())
            out["steady"]["cycles"] += steady
            out["warm-up"]["cycles"] += sum(counts.values()) - steady
        for alarm in run["alarms"]:
            if alarm["joint"] not in worn:
                out[alarm_stage(run, alarm)]["alarms"] += 1
    for tally in out.values():
        tally["due"] = tally["cycles"] / arl0
    return out


def report(runs: list[dict[str, Any]], arl0: float) -> str:
    lines = ["seed joint  wear  kl_raw  kl_weighted  joint   not tested (detector-cycles by reason)"]
    rows = [row for run in runs for row in coverage_rows(run)]
    for row in rows:
        s = row["shares"]
        cells = "  ".join(f"{100 * s[q]:5.1f}" if s.get(q) is not None else "    –" for q in
                          ("wear", "kl_raw", "kl_weighted", "joint"))
        lines.append(f"{row['seed']:>4} {row['joint']:>5}  {cells}   {row['not_tested'] or ''}")
    wear = [row["shares"].get("wear") or 0.0 for row in rows]
    best = [row["distribution"] for row in rows]
    lines.append(f"lowest share tested: wear score {100 * min(wear):.1f} %, best distribution detector "
                 f"{100 * min(best):.1f} % (over {len(rows)} joints)")
    for run in runs:
        for joint in run["worn"]:
            first = earliest_alarm(run, joint)
            text = "none" if first is None else (f"cycle {first['cycle']}, {first['quantity']} ({first['stage']}), "
                                                 f"true wear {first['wear']:.1f}")
            lines.append(f"seed {run['seed']} joint {joint} (worn): first alarm {text}")
    advised = [run["advisories"] for run in runs if "advisories" in run]
    if advised:
        lines.append(f"operating-range advisories per robot: {', '.join(map(str, advised))}")
    for stage, t in false_alarms(runs, arl0).items():
        low, high = poisson_interval(int(t["alarms"]), t["due"]) if t["due"] > 0 else (0.0, 0.0)
        ratio = t["alarms"] / t["due"] if t["due"] > 0 else float("nan")
        lines.append(f"{stage}: {t['alarms']} false alarms in {t['cycles']} tested detector-cycles of unworn joints, "
                     f"{t['due']:.2f} due at ARL0 {arl0:.3g} ({ratio:.2f}×, 95 % {low:.2f}–{high:.2f})")
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--seeds", required=True, help="e.g. 7101-7104 or 1,2,5")
    parser.add_argument("--cycles", type=int, default=None, help="cycles per robot (default: 1000, or the scenario's)")
    parser.add_argument("--scenario", help="simulator scenario: a TOML file or a packaged name (e.g. plant_week)")
    parser.add_argument("--no-motor-temperature", action="store_true", help="the controller sends none")
    parser.add_argument("--wear-ramp", action="append", default=[], metavar="JOINT:START:END:FROM:TO")
    parser.add_argument("--set", action="append", default=[], type=parse_set, metavar="TABLE.KEY=VALUE",
                        help="agent setting (TOML value), e.g. decision.budget_period=\"week\"")
    parser.add_argument("--from-series", action="store_true",
                        help="only the detectors, over the per-cycle quantities studies/series.py keeps (computed once "
                             "per code version; wear from the scenario file only)")
    parser.add_argument("--jobs", type=int, default=2)
    parser.add_argument("--json", type=Path, help="write the run records here")
    args = parser.parse_args(argv)
    logging.basicConfig(level=logging.INFO, format="%(asctime)s %(name)s %(message)s")
    cycles = args.cycles if args.cycles is not None else (None if args.scenario else 1000)
    overrides = tuple(args.set)
    try:
        arl0 = config_from_mapping(settings_from(overrides)).decision.arl0
    except ValueError as exc:
        parser.error(str(exc))
    specs = [RunSpec(seed, cycles, wear_ramps=tuple(args.wear_ramp), overrides=overrides, progress=200,
                     scenario=args.scenario, motor_temperature=not args.no_motor_temperature)
             for seed in parse_seeds(args.seeds)]
    if args.from_series and args.wear_ramp:
        parser.error("--from-series takes wear from the scenario file only (--wear-ramp changes the simulation)")
    with ProcessPoolExecutor(max(1, min(args.jobs, len(specs)))) as pool:
        runs = list(pool.map(run_robot_series if args.from_series else run_robot, specs))
    print(report(runs, arl0))
    if args.json:
        args.json.write_text(json.dumps(runs, indent=1) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
