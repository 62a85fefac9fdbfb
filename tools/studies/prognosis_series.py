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

from studies.prognosis_series import fleet  # noqa: E402
from studies.settings import parse_seeds  # noqa: E402


def seeds(text: str) -> list[int]:
    """``"4801-4806"``, ``"1,2,5"`` or ``""`` (none)."""
    return parse_seeds(text) if text.strip() else []


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--wear", default="4801-4806", help="seeds of wearing robots (default 4801-4806; '' none)")
    parser.add_argument("--healthy", default="4901", help="seeds of healthy robots (default 4901; '' none)")
    parser.add_argument("--jobs", type=int, default=2)
    parser.add_argument("--keep-series", action="store_true", help="use kept inputs of other code")
    args = parser.parse_args(argv)
    logging.basicConfig(level=logging.INFO, format="%(asctime)s %(name)s %(message)s")
    logging.getLogger("edge_monitor").setLevel(logging.ERROR)
    started = time.monotonic()
    for kind, text in (("wear", args.wear), ("healthy", args.healthy)):
        for r in fleet(kind, seeds(text), args.jobs, args.keep_series):
            print(f"{kind} seed {r['seed']}: {sum(len(v) for v in r['joints'].values())} joint-cycles")
    print(f"done in {time.monotonic() - started:.0f} s")
    return 0


if __name__ == "__main__":
    sys.exit(main())
