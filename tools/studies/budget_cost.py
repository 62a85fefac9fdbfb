#!/usr/bin/env python3
"""What a false-alarm budget costs in detection: wear at the first alarm for budgets of one false alarm
per robot-day, -week, -month and -year, on a slow, a medium and a fast wear ramp and a step
(docs/DETECTION.md, "The false-alarm budget"); one simulated joint per seed and ramp, one run for every
budget (studies.budgets says how).

Usage: ``python tools/studies/budget_cost.py [--seeds 301 302 303] [--jobs 2] [--json OUT] [--set TABLE.KEY=VALUE]``
(≈ 1–2 min CPU per run here).
"""

from __future__ import annotations

import os

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import argparse  # noqa: E402
import json  # noqa: E402
import logging  # noqa: E402
import sys  # noqa: E402
from concurrent.futures import ProcessPoolExecutor  # noqa: E402
from pathlib import Path  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))

from edge_monitor.pipeline.detectors import BUDGET_PERIODS  # noqa: E402
from studies.budgets import RAMPS, budgets, cost_table, run  # noqa: E402
from studies.settings import parse_set  # noqa: E402


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--seeds", type=int, nargs="+", default=[301, 302, 303])
    parser.add_argument("--ramps", nargs="+", default=list(RAMPS), choices=list(RAMPS))
    parser.add_argument("--jobs", type=int, default=2)
    parser.add_argument("--json", type=Path)
    parser.add_argument("--set", action="append", default=[], type=parse_set, metavar="TABLE.KEY=VALUE",
                        help="agent setting (value as JSON) on top of the shipped defaults, e.g. "
                             "decision.warm_up_hold_margin=4")
    args = parser.parse_args(argv)
    logging.basicConfig(level=logging.INFO, format="%(asctime)s %(name)s %(message)s")
    for name in ("edge_monitor", "sim_controller"):
        logging.getLogger(name).setLevel(logging.ERROR)
    overrides = tuple(args.set)
    jobs = [(seed, ramp, overrides) for ramp in args.ramps for seed in args.seeds]
    with ProcessPoolExecutor(max_workers=args.jobs) as pool:
        results = list(pool.map(run, *zip(*jobs)))
    print(cost_table(results))
    if args.json:
        args.json.write_text(json.dumps({"budgets": budgets(), "periods": BUDGET_PERIODS, "overrides": dict(overrides),
                                         "results": results}, indent=1) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
