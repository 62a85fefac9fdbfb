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
(the same inputs; minutes instead of an hour once the series are kept). The machinery is the package
``studies`` (studies.robots, studies.tally); this is its command line.

Usage: ``python tools/studies/healthy_fleet_study.py --cycles 200 --seeds 1 2 [--wear-ramp 2:100:200:0:60]
[--scenario load_step] [--set decision.allowance=0] [--from-series] [--json OUT]``.
"""

from __future__ import annotations

import os

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")     # before numpy loads: tiny matrices, a threaded BLAS only spins

import argparse  # noqa: E402
import json  # noqa: E402
import logging  # noqa: E402
import sys  # noqa: E402
from concurrent.futures import ProcessPoolExecutor  # noqa: E402
from pathlib import Path  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))

from studies.robots import DEFAULT_CYCLES, RunSpec, run_robot, run_robot_series  # noqa: E402
from studies.settings import parse_set  # noqa: E402
from studies.tally import summarise  # noqa: E402


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
