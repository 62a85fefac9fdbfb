#!/usr/bin/env python3
"""What the prognosis is fed, per joint and cycle, for the simulated fleet of docs/PROGNOSIS.md, computed
once and kept on disk: the wear estimate and its std, the joint's alarm state, the controller time and
the true wear (``edge_monitor/offline/prognosis_fleet.py``), so that the study replays only the trend
models (``tools/studies/prognosis_study.py``).

Robots: ``wear`` seeds (6 joints, one law each, the plant week up to the last joint's end of life) and
``healthy`` seeds (6 joints without wear, the whole plant week, 4 400 cycles). The cache
(``.cache/prognosis_series/``) is keyed by kind and seed and holds the hash of the code the inputs depend
on (simulator, joint model, the agent's features, detectors and pipeline, its defaults); another hash
recomputes, unless ``--keep-series`` accepts the kept inputs (the trend models do not change them).

Usage: ``python tools/studies/prognosis_series.py --wear 4801-4806 --healthy 4901 [--jobs 2]``.
"""

from __future__ import annotations

import os

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")     # tiny matrices: threaded BLAS only spins

import argparse  # noqa: E402
import gzip  # noqa: E402
import hashlib  # noqa: E402
import json  # noqa: E402
import logging  # noqa: E402
import sys  # noqa: E402
import time  # noqa: E402
from concurrent.futures import ProcessPoolExecutor  # noqa: E402
from pathlib import Path  # noqa: E402
from typing import Any  # noqa: E402

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT))

from edge_monitor.offline.prognosis_fleet import CycleRow, robot_config, robot_laws, robot_series  # noqa: E402

log = logging.getLogger("prognosis_series")

CACHE = ROOT / ".cache" / "prognosis_series"
#: Sources the recorded inputs depend on (the trend models, edge_monitor/stats/wear_trend*.py, do not).
SOURCES = ("joint_model", "sim_controller", "protocol/frames.py", "edge_monitor/features", "edge_monitor/stats",
           "edge_monitor/pipeline", "edge_monitor/config.py", "edge_monitor/defaults/agent.toml",
           "edge_monitor/offline/fast_path.py", "edge_monitor/offline/prognosis_fleet.py")
SKIPPED = ("wear_trend", "prognosis")

Robot = dict[str, Any]      # {"kind", "seed", "code", "laws": [...] | None, "joints": {joint: [row lists]}}


def code_hash() -> str:
    """SHA-256 (12 hex digits) of the sources in :data:`SOURCES`, the prognosis's own modules left out."""
    digest = hashlib.sha256()
    for name in SOURCES:
        path = ROOT / name
        for file in sorted(path.rglob("*")) if path.is_dir() else [path]:
            if (file.is_file() and file.suffix in (".py", ".toml") and "__pycache__" not in file.parts
                    and not any(s in file.name for s in SKIPPED)):
                digest.update(str(file.relative_to(ROOT)).encode())
                digest.update(file.read_bytes())
    return digest.hexdigest()[:12]


def compute(kind: str, seed: int) -> Robot:
    laws = robot_laws(seed) if kind == "wear" else None
    series = robot_series(robot_config(seed, laws))
    return {"kind": kind, "seed": seed, "code": code_hash(), "laws": None if laws is None else
            [law.to_dict() for law in laws], "joints": {str(j): [r.to_list() for r in rows] for j, rows in series.items()}}


def robot(kind: str, seed: int, keep: bool = False) -> Robot:
    """One robot's inputs, from the cache when it holds them for the current code (or ``keep``)."""
    path = CACHE / f"{kind}-seed{seed}.json.gz"
    if path.exists():
        with gzip.open(path, "rt") as f:
            kept = json.load(f)
        if keep or kept.get("code") == code_hash():
            return kept
        log.info("%s seed %d: kept inputs are of other code (%s); recomputing", kind, seed, kept.get("code"))
    started = time.monotonic()
    out = compute(kind, seed)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_suffix(".tmp")
    with gzip.open(tmp, "wt") as f:
        json.dump(out, f)
    tmp.replace(path)
    log.info("%s seed %d: %.0f s", kind, seed, time.monotonic() - started)
    return out


def rows(robot_inputs: Robot) -> dict[int, list[CycleRow]]:
    return {int(j): [CycleRow.from_list(r) for r in rows] for j, rows in robot_inputs["joints"].items()}


def fleet(kind: str, seeds: list[int], jobs: int = 1, keep: bool = False) -> list[Robot]:
    """:func:`robot` of every seed, in up to ``jobs`` processes."""
    if jobs < 2 or len(seeds) < 2:
        return [robot(kind, s, keep) for s in seeds]
    with ProcessPoolExecutor(min(jobs, len(seeds))) as pool:
        return list(pool.map(robot, [kind] * len(seeds), seeds, [keep] * len(seeds)))


def parse_seeds(text: str) -> list[int]:
    """``"4801-4806"`` or ``"1,2,5"`` (or a mix) → seeds."""
    seeds: list[int] = []
    for part in filter(None, text.split(",")):
        low, _, high = part.partition("-")
        seeds.extend(range(int(low), int(high or low) + 1))
    return seeds


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--wear", default="4801-4806", help="seeds of wearing robots (default 4801-4806)")
    parser.add_argument("--healthy", default="4901", help="seeds of healthy robots (default 4901)")
    parser.add_argument("--jobs", type=int, default=2)
    parser.add_argument("--keep-series", action="store_true", help="use kept inputs of other code")
    args = parser.parse_args(argv)
    logging.basicConfig(level=logging.INFO, format="%(asctime)s %(name)s %(message)s")
    started = time.monotonic()
    for kind, text in (("wear", args.wear), ("healthy", args.healthy)):
        for r in fleet(kind, parse_seeds(text), args.jobs, args.keep_series):
            print(f"{kind} seed {r['seed']}: {sum(len(v) for v in r['joints'].values())} joint-cycles")
    print(f"done in {time.monotonic() - started:.0f} s")
    return 0


if __name__ == "__main__":
    sys.exit(main())
