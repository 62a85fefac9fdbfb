"""TOML scenario files: everything the command-line flags cannot say (docs/SIMULATOR.md).

```toml
[simulation]              # any SimConfig field (scalars; ranges as [LOW, HIGH])
joints = 6
cycles = 400
temperature_range = [30, 70]

[faults]                  # FaultSpec fields
drop = 0.001

[[joint]]                 # per joint: index (0-based) or "all"
index = 2
wear_initial = 5
load_sign = -1
friction = { fc0 = 0.032 }          # absolute parameter values replacing the table
wear = [ { kind = "exponential", start = 100, end = 300, from = 5, to = 60, tau = 40 },
         { kind = "replacement", start = 320 } ]

[[timeline]]              # plant changes (sim_controller.timeline), in increasing cycle order
cycle = 620
load_range = [0.6, 1.0]
[[timeline]]
cycle = 900
stop_hours = 56
```

Every error names the field (``scenario.simulation.rate: …``, ``scenario.timeline[1].stop_hours: …``).
A scenario is a file path or the name of one shipped in ``sim_controller/scenarios/``
(:func:`packaged_scenarios`).
"""

from __future__ import annotations

import tomllib
from importlib import resources
from importlib.resources.abc import Traversable
from pathlib import Path
from typing import Any, Mapping, Sequence

from joint_model.friction import FrictionParams
from sim_controller.config import JointOverride, SimConfig, SimConfigError, merge_wear, wear_profiles_from_ramps
from sim_controller.faults import FaultSpec
from sim_controller.timeline import PlantEvent, TimelineError, check_order, plant_event_from_mapping
from sim_controller.wear_scenarios import WearEvent, WearProfile, WearScenarioError, event_from_mapping

_RANGE_FIELDS = {"load_range", "temperature_range", "p2p_delay"}
_SKIP_FIELDS = {"wear", "faults", "joint_overrides", "friction", "timeline"}
_TABLES = ("simulation", "faults", "joint", "timeline")
_JOINT_KEYS = {"index", "wear_initial", "wear", "friction", "load_sign"}


class ScenarioError(SimConfigError):
    """Invalid scenario file; the message names the field."""


def _field_types() -> dict[str, Any]:
    return {name: f.type for name, f in SimConfig.__dataclass_fields__.items() if name not in _SKIP_FIELDS}


def _convert(name: str, value: Any, where: str) -> Any:
    default = getattr(SimConfig(), name)
    if name in _RANGE_FIELDS:
        if not (isinstance(value, list) and len(value) == 2 and all(isinstance(v, (int, float)) for v in value)):
            raise ScenarioError(f"{where}.{name}: expected [LOW, HIGH], got {value!r}")
        return (float(value[0]), float(value[1]))
    if name == "speeds":
        if not (isinstance(value, list) and all(isinstance(v, (int, float)) for v in value)):
            raise ScenarioError(f"{where}.speeds: expected a list of speeds in rad/s, got {value!r}")
        return tuple(float(v) for v in value)
    if isinstance(default, bool) or isinstance(value, bool):
        raise ScenarioError(f"{where}.{name}: expected a number, got {value!r}")
    if isinstance(default, int) and not isinstance(default, bool) and name != "variation":
        if not isinstance(value, int):
            raise ScenarioError(f"{where}.{name}: expected an integer, got {value!r}")
        return value
    if not isinstance(value, (int, float)):
        raise ScenarioError(f"{where}.{name}: expected a number, got {value!r}")
    return float(value)


def packaged_scenarios() -> list[str]:
    """Names of the scenarios shipped in ``sim_controller/scenarios/`` (usable instead of a path)."""
    folder = resources.files("sim_controller") / "scenarios"
    return sorted(f.name[:-5] for f in folder.iterdir() if f.name.endswith(".toml"))


def scenario_source(name_or_path: str | Path) -> Path | Traversable:
    """The file of a scenario: an existing path, else the packaged scenario of that name (``.toml``
    optional); a :class:`ScenarioError` lists the packaged ones when it is neither."""
    path = Path(name_or_path)
    if path.exists():
        return path
    packaged = resources.files("sim_controller") / "scenarios" / (path.stem + ".toml")
    if path.parent == Path(".") and path.suffix in ("", ".toml") and packaged.is_file():
        return packaged
    raise ScenarioError(f"scenario: no file {str(name_or_path)!r} and no packaged scenario of that name; "
                        f"packaged: {', '.join(packaged_scenarios())}")


def load_scenario(path: str | Path, joints: int | None = None) -> dict[str, Any]:
    """Parse and validate a scenario (file path or packaged name) into ``SimConfig`` keyword arguments.

    ``joints`` (e.g. from the command line) overrides the file's joint count, so that
    ``index = "all"`` covers every joint that will run."""
    source = scenario_source(path)
    try:
        doc = tomllib.loads(source.read_text(encoding="utf-8"))
    except OSError as exc:
        raise ScenarioError(f"scenario: cannot read {path}: {exc.strerror or exc}") from None
    except UnicodeDecodeError as exc:
        raise ScenarioError(f"scenario: {path} is not UTF-8 text ({exc.reason} at byte {exc.start}); save it "
                            "as UTF-8") from None
    except tomllib.TOMLDecodeError as exc:
        raise ScenarioError(f"scenario: {path} is not valid TOML: {exc}") from None
    return scenario_from_mapping(doc, joints)


def scenario_config(scenario: str | Path | None, fields: Mapping[str, Any], *,
                    fallback: Mapping[str, Any] | None = None, wear_ramps: Sequence[str] = ()) -> SimConfig:
    """A study's ``SimConfig``: the ``scenario`` (file or packaged name; ``None``: none) with ``fields``
    set over it (e.g. each robot's seed), ``fallback`` for what neither sets (e.g. a study's default
    length), and ``--wear-ramp`` specs added to the scenario's wear (``index = "all"`` covers
    ``fields["joints"]`` joints when given)."""
    given = {key: value for key, value in fields.items() if value is not None}
    kwargs = {**(fallback or {}), **(load_scenario(scenario, given.get("joints")) if scenario else {}), **given}
    if wear_ramps:
        joints = int(kwargs.get("joints", SimConfig().joints))
        kwargs["wear"] = merge_wear(kwargs.get("wear", ()), wear_profiles_from_ramps(wear_ramps, joints), joints)
    return SimConfig(**kwargs)


def scenario_from_mapping(doc: dict[str, Any], joints: int | None = None) -> dict[str, Any]:
    unknown = sorted(set(doc) - set(_TABLES))
    if unknown:
        raise ScenarioError(f"scenario: unknown table(s) {unknown}; use [simulation], [faults], [[joint]], "
                            "[[timeline]]")
    kwargs: dict[str, Any] = {}
    sim = doc.get("simulation", {})
    if not isinstance(sim, dict):
        raise ScenarioError("scenario.simulation: expected a table")
    types = _field_types()
    for name, value in sim.items():
        if name not in types:
            raise ScenarioError(f"scenario.simulation.{name}: unknown field; known: {', '.join(sorted(types))}")
        kwargs[name] = _convert(name, value, "scenario.simulation")
    faults = doc.get("faults", {})
    if not isinstance(faults, dict):
        raise ScenarioError("scenario.faults: expected a table")
    try:
        known = set(FaultSpec.__dataclass_fields__)
        bad = sorted(set(faults) - known)
        if bad:
            raise ScenarioError(f"scenario.faults: unknown field(s) {bad}; known: {', '.join(sorted(known))}")
        kwargs["faults"] = FaultSpec(**{k: float(v) for k, v in faults.items()})
    except (TypeError, ValueError) as exc:
        raise ScenarioError(f"scenario.faults: {exc}") from None
    if joints is None:
        joints = int(kwargs.get("joints", SimConfig().joints))
    if not 1 <= joints <= 8:
        raise ScenarioError(f"scenario.simulation.joints: must be 1 … 8, got {joints}")
    wear, overrides = _joints(doc.get("joint", []), joints)
    kwargs["wear"] = wear
    kwargs["joint_overrides"] = overrides
    kwargs["timeline"] = _timeline(doc.get("timeline", []))
    return kwargs


def _timeline(tables: Any) -> tuple[PlantEvent, ...]:
    if not isinstance(tables, list):
        raise ScenarioError("scenario.timeline: expected [[timeline]] tables, e.g. { cycle = 620, "
                            "load_range = [0.6, 1.0] }")
    events = []
    try:
        for n, table in enumerate(tables):
            if not isinstance(table, dict):
                raise ScenarioError(f"scenario.timeline[{n}]: expected a table, got {table!r}")
            events.append(plant_event_from_mapping(table, f"scenario.timeline[{n}]"))
        check_order(events, "scenario.timeline")
    except TimelineError as exc:
        raise ScenarioError(str(exc)) from None
    return tuple(events)


def _joints(tables: Any, joints: int) -> tuple[tuple[WearProfile, ...], tuple[JointOverride | None, ...]]:
    if not isinstance(tables, list):
        raise ScenarioError("scenario.joint: expected [[joint]] tables")
    initial = [0.0] * joints
    events: list[list[WearEvent]] = [[] for _ in range(joints)]
    overrides: list[JointOverride | None] = [None] * joints
    for n, table in enumerate(tables):
        where = f"scenario.joint[{n}]"
        if not isinstance(table, dict):
            raise ScenarioError(f"{where}: expected a table")
        bad = sorted(set(table) - _JOINT_KEYS)
        if bad:
            raise ScenarioError(f"{where}: unknown field(s) {bad}; known: {', '.join(sorted(_JOINT_KEYS))}")
        index = table.get("index")
        if index == "all":
            targets = list(range(joints))
        elif isinstance(index, int) and not isinstance(index, bool) and 0 <= index < joints:
            targets = [index]
        else:
            raise ScenarioError(f"{where}.index: unknown joint {index!r}; use 0 … {joints - 1} or \"all\"")
        try:
            new_events = [event_from_mapping(e, f"{where}.wear[{i}]") if isinstance(e, dict) else
                          _raise(f"{where}.wear[{i}]: expected a table") for i, e in enumerate(table.get("wear", []))]
            friction = None
            if "friction" in table:
                if not isinstance(table["friction"], dict):
                    raise ScenarioError(f"{where}.friction: expected a table of parameters")
                friction = FrictionParams.from_mapping(table["friction"], where=f"{where}.friction")
            load_sign = table.get("load_sign")
            if load_sign is not None and load_sign not in (-1, 1):
                raise ScenarioError(f"{where}.load_sign: must be 1 or -1, got {load_sign!r}")
            for j in targets:
                if "wear_initial" in table:
                    initial[j] = float(table["wear_initial"])
                events[j].extend(new_events)
                if friction is not None or load_sign is not None:
                    overrides[j] = JointOverride(friction=friction,
                                                 load_sign=None if load_sign is None else float(load_sign))
        except (WearScenarioError, TypeError) as exc:
            raise ScenarioError(str(exc)) from None
        except ValueError as exc:
            raise ScenarioError(str(exc) if str(exc).startswith(where) else f"{where}: {exc}") from None
    try:
        profiles = tuple(WearProfile(initial=initial[j], events=tuple(events[j])) for j in range(joints))
    except WearScenarioError as exc:
        raise ScenarioError(f"scenario.joint.wear_initial: {exc}") from None
    return profiles, tuple(overrides)


def _raise(message: str) -> WearEvent:
    raise ScenarioError(message)
