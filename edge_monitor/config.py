"""Agent configuration from a TOML file with embedded defaults, and command-line overrides.

This module only parses: types are coerced here (with messages naming ``section.key``), values are
validated by the components' own config dataclasses (:mod:`edge_monitor.pipeline.agent_config`).
The shipped example ``edge_monitor/defaults/agent.toml`` documents every key; ``edge-monitor
commission`` writes the ``[friction]`` section.
"""

from __future__ import annotations

import dataclasses
import re
import tomllib
from pathlib import Path
from typing import Any, Mapping

from edge_monitor.errors import ConfigError, key_name, shown
from edge_monitor.features.joint_model_learning import ModelConfig
from edge_monitor.features.kl_monitor import KLConfig
from edge_monitor.features.prognosis import PrognosisConfig
from edge_monitor.features.segmentation import PlateauConfig
from edge_monitor.features.wear import WearConfig
from edge_monitor.pipeline.agent_config import AgentConfig
from edge_monitor.pipeline.decision_config import DecisionConfig
from edge_monitor.pipeline.fault_grouping import AlarmConfig
from edge_monitor.records import is_finite_number
from edge_monitor.sinks.acknowledge import AcknowledgeConfig
from edge_monitor.sinks.maintenance import MaintenanceConfig
from joint_model import FrictionParams
from protocol.files import NotARegularFile, read_regular
from protocol.frames import MAX_JOINTS

__all__ = ["AgentConfig", "ConfigError", "DecisionConfig", "KLConfig", "ModelConfig", "PlateauConfig", "WearConfig",
           "config_from_mapping", "load_config", "with_overrides"]


def _coerce(where: str, value: Any, default: Any) -> Any:
    """Convert a TOML value to the type of the dataclass default, with a message naming ``where``."""
    if isinstance(default, bool):
        if not isinstance(value, bool):
            raise ConfigError(f"{where}: expected true or false, got {value!r}")
        return value
    if isinstance(default, int) and not isinstance(default, bool):
        if isinstance(value, bool) or not isinstance(value, int):
            raise ConfigError(f"{where}: expected an integer, got {value!r}")
        return value
    if isinstance(default, float):
        if not is_finite_number(value):
            raise ConfigError(f"{where}: expected a finite number, got {shown(value)}")
        return float(value)
    if isinstance(default, str) or (default is None and isinstance(value, str)):
        if not isinstance(value, str):
            raise ConfigError(f"{where}: expected a string, got {value!r}")
        return value
    if default is None and isinstance(value, (int, float)) and not isinstance(value, bool):   # optional number
        if not is_finite_number(value):
            raise ConfigError(f"{where}: expected a finite number, got {shown(value)}")
        return float(value)
    if isinstance(default, tuple) or default is None:
        if not isinstance(value, list):
            raise ConfigError(f"{where}: expected a list, got {value!r}")
        return tuple(value)
    return value


def _coerce_fields(cls: type, values: Mapping[str, Any], where: str,
                   known: frozenset[str] | None = None) -> dict[str, Any]:
    """Values of ``cls`` fields (only ``known`` ones if given), typed like the field defaults."""
    if not isinstance(values, Mapping):
        raise ConfigError(f"{where}: expected a table, got {values!r}")
    known = known if known is not None else frozenset(f.name for f in dataclasses.fields(cls))
    unknown = sorted(set(values) - known)
    if unknown:
        names = ", ".join(f"{where}.{key_name(k)}" for k in unknown)
        raise ConfigError(f"{names}: unknown key; known keys of [{where}]: {sorted(known)}")
    defaults = cls()
    return {key: _coerce(f"{where}.{key}", raw, getattr(defaults, key)) for key, raw in values.items()}


def _section(cls: type, values: Mapping[str, Any], where: str) -> Any:
    kwargs = _coerce_fields(cls, values, where)
    try:
        return cls(**kwargs)
    except ValueError as exc:
        raise ConfigError(str(exc)) from None


def config_from_mapping(data: Mapping[str, Any]) -> AgentConfig:
    """Build a validated configuration from a parsed TOML document."""
    data = dict(data)
    kwargs: dict[str, Any] = {}
    sections = {"segmentation": PlateauConfig, "model": ModelConfig, "wear": WearConfig, "kl": KLConfig,
                "decision": DecisionConfig, "prognosis": PrognosisConfig, "alarms": AlarmConfig,
                "maintenance": MaintenanceConfig, "acknowledge": AcknowledgeConfig}
    decision = dict(data.get("decision", {})) if isinstance(data.get("decision", {}), Mapping) else {}
    if isinstance(data.get("joints"), list) and data["joints"] and "joints_per_robot" not in decision:
        data["decision"] = {**decision, "joints_per_robot": len(data["joints"])}  # the budget's split
    for name, cls in sections.items():
        if name in data:
            kwargs[name] = _section(cls, data.pop(name), name)
    if "friction" in data:
        try:
            kwargs["friction"] = FrictionParams.from_mapping(data.pop("friction"), "friction")
        except ValueError as exc:
            raise ConfigError(str(exc)) from None
    if "joint" in data:
        kwargs["joint_friction"], kwargs["joint_critical_wear"] = _joint_tables(data.pop("joint"))
    if "zenoh" in data:
        if not isinstance(data["zenoh"], Mapping):
            raise ConfigError("zenoh: expected a table")
        kwargs["zenoh"] = dict(data.pop("zenoh"))
    for key in _PATH_KEYS & data.keys():
        _check_path(f"config.{key}", data[key])
    kwargs.update(_coerce_fields(AgentConfig, data, "config", _TOP_LEVEL_KEYS))
    try:
        return AgentConfig(**kwargs)
    except ValueError as exc:
        raise ConfigError(str(exc)) from None


#: Top-level keys whose value is a path (a number or a list there would reach the file system as one),
#: with an example of each.
_PATH_KEYS = {"state_dir": "/var/lib/edge-monitor", "jsonl": "symptoms.jsonl"}


def _check_path(where: str, value: Any) -> None:
    """ConfigError unless ``value`` is a non-empty path without a NUL character."""
    key = where.rsplit(".", 1)[-1]
    example = f'{key} = "{_PATH_KEYS[key]}"'
    if not isinstance(value, str) or not value.strip():
        raise ConfigError(f"{where}: expected a path (text), got {shown(value)}; write it quoted ({example}) "
                          "or omit the key")
    if "\0" in value:
        raise ConfigError(f"{where}: {shown(value)} holds a NUL character, which no path can; write the path "
                          f"without it ({example})")


def _joint_tables(tables: Any) -> tuple[dict[int, FrictionParams], dict[int, float]]:
    """``[joint.N.friction]`` tables and ``[joint.N] critical_wear`` values by joint."""
    joint_friction, critical = {}, {}
    if not isinstance(tables, Mapping):
        raise ConfigError("joint: expected tables [joint.N] (critical_wear) and [joint.N.friction]")
    for key, table in tables.items():
        if not re.fullmatch(r"[0-9]{1,3}", str(key)) or not 0 <= int(key) < MAX_JOINTS:
            raise ConfigError(f"joint.{key_name(key)}: joint index must be 0 … {MAX_JOINTS - 1}")
        if not isinstance(table, Mapping) or set(table) - {"friction", "critical_wear"}:
            raise ConfigError(f"joint.{key}: expected only critical_wear and a [joint.{key}.friction] table")
        if "friction" in table:
            try:
                joint_friction[int(key)] = FrictionParams.from_mapping(table["friction"], f"joint.{key}.friction")
            except ValueError as exc:
                raise ConfigError(str(exc)) from None
        if "critical_wear" in table:
            critical[int(key)] = _coerce(f"joint.{key}.critical_wear", table["critical_wear"], 0.0)
    return joint_friction, critical


#: Plain keys at the top of the TOML file (the structured fields have tables of their own).
_TOP_LEVEL_KEYS = frozenset(f.name for f in dataclasses.fields(AgentConfig)) - {
    "friction", "joint_friction", "joint_critical_wear", "segmentation", "model", "wear", "kl", "decision", "prognosis",
    "alarms", "maintenance", "acknowledge", "zenoh"}


#: The shipped example config, where this installation has it (every key with its default and meaning).
EXAMPLE_CONFIG = Path(__file__).resolve().parent / "defaults" / "agent.toml"


#: Largest config file read [bytes]: the shipped example is ≈ 8 kB.
MAX_CONFIG_BYTES = 1 << 20


def load_config(path: str | Path | None) -> AgentConfig:
    """Load a TOML config file; ``None`` gives the embedded defaults. Only a regular file of at most
    :data:`MAX_CONFIG_BYTES` is read (a FIFO or a device never blocks or floods memory); tables nested
    too deeply for the parser are a :class:`ConfigError` like any other invalid TOML."""
    if path is None:
        return AgentConfig()
    p = Path(path)
    fix = "pass a readable UTF-8 TOML file (example: edge_monitor/defaults/agent.toml)"
    try:
        text = read_regular(p, MAX_CONFIG_BYTES).decode("utf-8")
        data = tomllib.loads(text)
    except FileNotFoundError:
        raise ConfigError(f"config file {p} not found; pass an existing TOML file "
                          f"(the example with every key: {EXAMPLE_CONFIG})") from None
    except tomllib.TOMLDecodeError as exc:
        raise ConfigError(f"config file {p}: invalid TOML: {exc}") from None
    except NotARegularFile as exc:
        raise ConfigError(f"config file {p}: {exc.reason}; {fix}") from None
    except RecursionError:
        raise ConfigError(f"config file {p}: invalid TOML: tables or arrays nested too deeply; {fix}") from None
    except (OSError, UnicodeDecodeError, ValueError) as exc:
        raise ConfigError(f"config file {p}: cannot read it ({getattr(exc, 'strerror', None) or exc}); "
                          f"{fix}") from None
    return config_from_mapping(data)


def with_overrides(cfg: AgentConfig, **overrides: Any) -> AgentConfig:
    """Apply command-line overrides (``None`` means: keep the config value)."""
    changes = {k: v for k, v in overrides.items() if v is not None}
    return dataclasses.replace(cfg, **changes) if changes else cfg
