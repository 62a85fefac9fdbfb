#!/usr/bin/env python3
"""Compute and keep the per-cycle quantities of simulated robots (studies.series: the fast path with the
detectors off, cached in ``.cache/fleet_series/`` per code version), so that detector studies replay only
the detectors (tools/studies/arl_study.py, tools/studies/healthy_fleet_study.py; docs/DETECTION.md).

Usage: ``python tools/studies/fleet_series.py --seeds 101-108 --cycles 1100 [--joints 6] [--scenario FILE]
[--no-motor-temperature] [--jobs 2]`` prints one status line per robot and the cache files.
"""

from __future__ import annotations

import os

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")     # tiny matrices: threaded BLAS only spins

import argparse  # noqa: E402
import logging  # noqa: E402
import sys  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))

from studies.series import cache_path, fleet  # noqa: E402
from studies.settings import parse_seeds  # noqa: E402


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--seeds", default="101-108", help="seeds, e.g. 101-108 or 1,2,5 (default 101-108)")
    parser.add_argument("--cycles", type=int, default=1100)
    parser.add_argument("--joints", type=int, default=6)
    parser.add_argument("--scenario", help="simulator scenario: a TOML file or a packaged name (e.g. plant_week)")
    parser.add_argument("--no-motor-temperature", action="store_true", help="the controller sends none")
    parser.add_argument("--jobs", type=int, default=max(1, min(os.cpu_count() or 1, 4)))
    args = parser.parse_args(argv)
    logging.basicConfig(level=logging.INFO, format="%(asctime)s %(name)s %(message)s")
    seeds = parse_seeds(args.seeds)
    started = time.monotonic()
    motor = not args.no_motor_temperature
    series = fleet(seeds, args.cycles, args.joints, args.scenario, args.jobs, motor)
    for seed, robot in zip(seeds, series):
        print(f"seed {seed}: {sum(len(r) for r in robot.values())} joint-cycles "
              f"→ {cache_path(seed, args.cycles, args.joints, args.scenario, motor_temperature=motor).name}")
    print(f"{len(seeds)} robots in {time.monotonic() - started:.0f} s")
    return 0


if __name__ == "__main__":
    sys.exit(main())
