#!/usr/bin/env python3
"""Compute and keep what the prognosis is fed for the simulated fleet of docs/PROGNOSIS.md
(:mod:`studies.prognosis_series`; ``tools/studies/prognosis_study.py`` replays the trend models on it).

Usage: ``python tools/studies/prognosis_series.py --wear 4801-4806 --healthy 4901 [--jobs 2]`` (≈ 5–20 min
per robot on the fast path, depending on what else runs); ``--keep-series`` accepts inputs kept by other code.
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

from studies.prognosis_series import add_fleet_arguments, fleets  # noqa: E402


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    add_fleet_arguments(parser)
    args = parser.parse_args(argv)
    logging.basicConfig(level=logging.INFO, format="%(asctime)s %(name)s %(message)s")
    logging.getLogger("edge_monitor").setLevel(logging.ERROR)
    started = time.monotonic()
    for robots in fleets(args):
        for r in robots:
            print(f"{r['kind']} seed {r['seed']}: {sum(len(v) for v in r['joints'].values())} joint-cycles")
    print(f"done in {time.monotonic() - started:.0f} s")
    return 0


if __name__ == "__main__":
    sys.exit(main())
