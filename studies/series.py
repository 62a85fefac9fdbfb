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
content and a hash of the code the quantities depend on (simulator, joint model, features, fast path,
defaults; the defaults by their settings without comments and without ``[decision]``, which the detectors
alone read), so a code change recomputes. :func:`fleet` runs robots in parallel processes. The command
line is tools/studies/fleet_series.py.
"""

from __future__ import annotations

import gzip
import hashlib
import json
import logging
import time
import tomllib
from concurrent.futures import ProcessPoolExecutor
from dataclasses import replace
from pathlib import Path
from typing import Any, Iterator

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
            if file.is_file() and file.suffix in (".py", ".toml") and "__pycache__" not in file.parts:
                digest.update(str(file.relative_to(ROOT)).encode())
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
    config = _config(seed, cycles, joints, scenario)
    out: Series = {}
    started = time.monotonic()
    kept = ("motor_temperature",) * motor_temperature + ("temperature", "load", "wear")
    for joint, cycle, values, truth in _detector_inputs(config, motor_temperature):
        out.setdefault(joint, []).append({"cycle": cycle, **values, **{k: float(truth[k]) for k in kept if k in truth}})
        if joint == 0 and cycle % 100 == 99:
            log.info("seed %d: cycle %d/%d, %.0f s", seed, cycle + 1, cycles, time.monotonic() - started)
    return out


Row = tuple[int, int, dict[str, float], dict[str, Any]]


def _detector_inputs(config: Any, motor_temperature: bool) -> Iterator[Row]:
    """The fast path's detector inputs with the truth (edge_monitor.offline.fast_path.detector_inputs_with_truth);
    without motor temperature, the same from cycles whose status frames carry none, each row's values with the wear
    estimate's ``friction_temperature`` added. (Written here rather than as an option of the fast path, whose code
    keys every kept series.)"""
    from edge_monitor.config import config_from_mapping
    from edge_monitor.offline.fast_path import CycleFeeder, detector_inputs_with_truth
    from edge_monitor.pipeline.agent import Agent
    from sim_controller.cycle_mode import cycle_signals

    if motor_temperature:
        yield from detector_inputs_with_truth(config)
        return
    feeder = CycleFeeder(Agent(config_from_mapping({"decision": {"enabled": False}})))
    truth: dict[tuple[int, int], dict[str, Any]] = {}

    def rows(symptoms: list[Any]) -> Iterator[Row]:
        for symptom in symptoms:
            record = symptom.to_dict()
            wear, kl = record.get("wear") or {}, record.get("kl") or {}
            known = truth.pop((int(record["cycle"]), int(record["joint"])), {})
            values = {"wear_score": wear.get("score"), "kl_raw": kl.get("raw"), "kl_weighted": kl.get("weighted"),
                      "friction_temperature": wear.get("temperature")}
            if all(v is not None for v in values.values()):
                yield int(record["joint"]), int(record["cycle"]), {k: float(v or 0.0) for k, v in values.items()}, known

    for signals in cycle_signals(config):
        truth.update({(signals.cycle, j): t for j, t in enumerate(signals.truth)})
        yield from rows(feeder.update(without_motor_temperature(signals)))
    yield from rows(feeder.finish())


def without_motor_temperature(signals: Any) -> Any:
    """The cycle (``CycleSignals``) as a controller that sends no motor temperature sends it."""
    import numpy as np

    joints = [replace(j, motor_temperature=np.full_like(j.motor_temperature, np.nan)) for j in signals.joints]
    return replace(signals, joints=joints)


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
