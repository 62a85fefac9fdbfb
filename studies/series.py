"""Per-cycle quantities of simulated robots, computed once and kept on disk, so that detector studies
replay only the detectors (docs/DETECTION.md).

Each robot is one seed of the simulator (defaults: 6 joints with individual variation, the thermal
model, the load spread; a scenario adds e.g. a plant timeline) run through the agent's features on the
fast path with its detectors off. Per joint and cycle a row holds the detector inputs (``wear_score``,
``kl_raw``, ``kl_weighted``), the cycle's motor temperature as the controller reports it (the detectors'
thermal settling test watches it) and the simulator's truth (lubricant ``temperature`` [°C], ``load``,
``wear``). A row is kept from the cycle the joint's features give values on (after its model and KL
nominal are learned). A robot whose controller sends no motor temperature (``motor_temperature=False``)
has none in its rows; they carry ``friction_temperature``, the lubricant temperature its wear estimate
reads from the friction, which its detectors follow instead (studies.bank_replay.detectors_temperature).

The cache (:data:`CACHE`, ``.cache/fleet_series/``) is keyed by seed, joints, cycles, the scenario's
content and a hash of the code the quantities depend on (simulator but its file and link writers, joint
model, features, fast path, defaults; the defaults by their settings without comments and without
``[decision]``, which the detectors alone read), so a code change recomputes. :func:`fleet` runs robots
in parallel processes. The command line is tools/studies/fleet_series.py.
"""

from __future__ import annotations

import gzip
import hashlib
import json
import logging
import time
import tomllib
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path
from typing import Any

#: The repository the code hash reads and the cache lives in.
ROOT = Path(__file__).resolve().parents[1]

log = logging.getLogger(__name__)

#: Where the series are kept (git-ignored).
CACHE = ROOT / ".cache" / "fleet_series"
#: Sources the per-cycle quantities depend on (the detectors do not: they are off here).
SOURCES = ("joint_model", "sim_controller", "protocol/frames.py", "edge_monitor/features", "edge_monitor/config.py",
           "edge_monitor/defaults/agent.toml", "edge_monitor/offline/fast_path.py",
           "edge_monitor/pipeline/cycle_assembly.py", "edge_monitor/pipeline/joint_monitor.py",
           "edge_monitor/pipeline/agent.py", "edge_monitor/sources/ingest.py", "edge_monitor/sources/samples.py",
           "edge_monitor/sources/cycle_arrays.py")
#: Of those, what writes frames to files and links, which the fast path never uses: a change there keeps them.
NOT_SOURCES = ("sim_controller/cli.py", "sim_controller/output.py", "sim_controller/log_writers.py")

#: Per joint, its rows in cycle order (see the module docstring).
Series = dict[int, list[dict[str, float]]]


def code_hash() -> str:
    """SHA-256 (12 hex digits) of every source file the quantities depend on; a TOML file by its settings,
    without its comments and its ``[decision]`` table (the detectors are off here), so a comment or a
    detector setting does not make the kept series stale."""
    digest = hashlib.sha256()
    for name in SOURCES:
        path = ROOT / name
        files = sorted(path.rglob("*")) if path.is_dir() else [path]
        for file in files:
            relative = file.relative_to(ROOT).as_posix()
            if (file.is_file() and file.suffix in (".py", ".toml") and "__pycache__" not in file.parts
                    and relative not in NOT_SOURCES):
                digest.update(relative.encode())
                digest.update(settings_bytes(file) if file.suffix == ".toml" else file.read_bytes())
    return digest.hexdigest()[:12]


def settings_bytes(file: Path) -> bytes:
    """A TOML file's settings other than ``[decision]``, canonically."""
    settings = tomllib.loads(file.read_text(encoding="utf-8"))
    settings.pop("decision", None)
    return json.dumps(settings, sort_keys=True, default=str).encode()


def _config(seed: int, cycles: int, joints: int, scenario: str | None) -> Any:
    from sim_controller.scenario import scenario_config

    return scenario_config(scenario, {"joints": joints, "cycles": cycles, "seed": seed})


def cache_path(seed: int, cycles: int, joints: int, scenario: str | None, code: str | None = None,
               motor_temperature: bool = True) -> Path:
    """The file one robot's series are kept in, for the code as it is now (or as of ``code``, a :func:`code_hash`)."""
    tag = "default" if scenario is None else \
        hashlib.sha256(repr(_config(seed, cycles, joints, scenario)).encode()).hexdigest()[:10]
    sensor = "" if motor_temperature else "-no-motor-temperature"
    return CACHE / f"seed{seed}-j{joints}-c{cycles}-{tag}{sensor}-{code or code_hash()}.json.gz"


def compute(seed: int, cycles: int, joints: int = 6, scenario: str | None = None,
            motor_temperature: bool = True) -> Series:
    """Per joint, the rows of every cycle with feature values (see the module docstring)."""
    from edge_monitor.offline.fast_path import detector_inputs_with_truth

    config = _config(seed, cycles, joints, scenario)
    out: Series = {}
    started = time.monotonic()
    kept = ("motor_temperature",) * motor_temperature + ("temperature", "load", "wear")
    for joint, cycle, values, truth in detector_inputs_with_truth(config, motor_temperature=motor_temperature):
        out.setdefault(joint, []).append({"cycle": cycle, **values, **{k: float(truth[k]) for k in kept if k in truth}})
        if joint == 0 and cycle % 100 == 99:
            log.info("seed %d: cycle %d/%d, %.0f s", seed, cycle + 1, cycles, time.monotonic() - started)
    return out


def robot_series(seed: int, cycles: int, joints: int = 6, scenario: str | None = None,
                 motor_temperature: bool = True) -> Series:
    """:func:`compute`, from the cache when it holds this robot for the current code."""
    path = cache_path(seed, cycles, joints, scenario, motor_temperature=motor_temperature)  # before computing
    if path.exists():
        with gzip.open(path, "rt") as f:
            return {int(j): rows for j, rows in json.load(f).items()}
    series = compute(seed, cycles, joints, scenario, motor_temperature)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_suffix(".tmp")
    with gzip.open(tmp, "wt") as f:
        json.dump({str(j): rows for j, rows in series.items()}, f)
    tmp.replace(path)
    return series


def fleet(seeds: list[int], cycles: int, joints: int = 6, scenario: str | None = None, jobs: int = 1,
          motor_temperature: bool = True) -> list[Series]:
    """:func:`robot_series` of every seed, in up to ``jobs`` processes."""
    if jobs < 2 or len(seeds) < 2:
        return [robot_series(s, cycles, joints, scenario, motor_temperature) for s in seeds]
    with ProcessPoolExecutor(min(jobs, len(seeds))) as pool:
        return list(pool.map(robot_series, seeds, [cycles] * len(seeds), [joints] * len(seeds),
                             [scenario] * len(seeds), [motor_temperature] * len(seeds)))
