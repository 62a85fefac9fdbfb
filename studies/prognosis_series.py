"""What the prognosis is fed, per joint and cycle, for the simulated fleet of docs/PROGNOSIS.md, computed
once per code version and kept in ``.cache/prognosis_series/``: the wear estimate and its std, the joint's
alarm state, the controller time and the true wear (:mod:`studies.prognosis_fleet`), so that the study
replays only the trend models (``tools/studies/prognosis_study.py``).

Robots: ``wear`` seeds (6 joints, one law each, the plant week up to the last joint's end of life) and
``healthy`` seeds (6 joints without wear, the whole plant week, 4 400 cycles). A kept robot holds the hash
of the code its inputs depend on (simulator, joint model, the agent's features, detectors, sources and
pipeline, its defaults; the prognosis's own modules left out); another hash recomputes it, unless ``keep``
accepts the kept inputs (the trend is the last step of a joint's cycle and feeds nothing back).
"""

from __future__ import annotations

import argparse
import gzip
import hashlib
import json
import logging
import time
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path
from typing import Any

from studies.prognosis_fleet import CycleRow, known_model_settings, robot_config, robot_laws, robot_series
from studies.settings import parse_seeds

log = logging.getLogger(__name__)

ROOT = Path(__file__).resolve().parents[1]
CACHE = ROOT / ".cache" / "prognosis_series"
#: Sources the recorded inputs depend on.
SOURCES = ("joint_model", "sim_controller", "protocol/frames.py", "edge_monitor/features", "edge_monitor/stats",
           "edge_monitor/sources", "edge_monitor/pipeline", "edge_monitor/config.py",
           "edge_monitor/defaults/agent.toml", "edge_monitor/offline/fast_path.py", "studies/prognosis_fleet.py")
#: The prognosis's own modules (file stems): the inputs do not depend on them. Matched whole: a part of a name
#: (``prognosis``) also left out this study's own ``prognosis_fleet.py``, so its changes kept stale inputs.
SKIPPED = ("wear_trend", "trend_mixture", "crossing_time", "prognosis")
#: "known_model": the wearing robots again, every joint given its true friction model (the error budget).
KINDS = ("wear", "healthy", "known_model")

Robot = dict[str, Any]      # {"kind", "seed", "code", "laws": [...] | None, "joints": {joint: [row lists]}}


def code_hash() -> str:
    """SHA-256 (12 hex digits) of the sources in :data:`SOURCES`, the prognosis's own modules left out."""
    digest = hashlib.sha256()
    for name in SOURCES:
        path = ROOT / name
        for file in sorted(path.rglob("*")) if path.is_dir() else [path]:
            if (file.is_file() and file.suffix in (".py", ".toml") and "__pycache__" not in file.parts
                    and file.stem not in SKIPPED):
                digest.update(str(file.relative_to(ROOT)).encode())
                digest.update(file.read_bytes())
    return digest.hexdigest()[:12]


def compute(kind: str, seed: int) -> Robot:
    """One robot's inputs (``kind`` one of :data:`KINDS`), through the whole agent on the fast path."""
    if kind not in KINDS:
        raise ValueError(f"kind: {kind!r}; use one of {KINDS}")
    laws = None if kind == "healthy" else robot_laws(seed)
    config = robot_config(seed, laws)
    series = robot_series(config, known_model_settings(config) if kind == "known_model" else None)
    joints = {str(j): [r.to_list() for r in rows] for j, rows in series.items()}
    return {"kind": kind, "seed": seed, "code": code_hash(),
            "laws": None if laws is None else [law.to_dict() for law in laws], "joints": joints}


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
    """Per joint, the kept rows of one robot."""
    return {int(j): [CycleRow.from_list(r) for r in rows] for j, rows in robot_inputs["joints"].items()}


def fleet(kind: str, seeds: list[int], jobs: int = 1, keep: bool = False) -> list[Robot]:
    """:func:`robot` of every seed, in up to ``jobs`` processes."""
    if jobs < 2 or len(seeds) < 2:
        return [robot(kind, s, keep) for s in seeds]
    with ProcessPoolExecutor(min(jobs, len(seeds))) as pool:
        return list(pool.map(robot, [kind] * len(seeds), seeds, [keep] * len(seeds)))


def add_fleet_arguments(parser: argparse.ArgumentParser) -> None:
    """The drivers' robots: ``--wear``, ``--healthy`` (seeds, ``''`` for none), ``--jobs``, ``--keep-series``."""
    parser.add_argument("--wear", default="4801-4806", help="seeds of wearing robots (default 4801-4806; '' none)")
    parser.add_argument("--healthy", default="4901", help="seeds of healthy robots (default 4901; '' none)")
    parser.add_argument("--jobs", type=int, default=2, help="processes (default 2)")
    parser.add_argument("--keep-series", action="store_true", help="use inputs kept by other code")


def fleets(args: argparse.Namespace) -> tuple[list[Robot], list[Robot]]:
    """(wearing, healthy) robots of :func:`add_fleet_arguments`'s arguments."""
    def seeds(text: str) -> list[int]:
        return parse_seeds(text) if text.strip() else []
    return (fleet("wear", seeds(args.wear), args.jobs, args.keep_series),
            fleet("healthy", seeds(args.healthy), args.jobs, args.keep_series))
