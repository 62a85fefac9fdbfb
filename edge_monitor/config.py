"""Agent configuration: a TOML file with embedded defaults, validated at start.

Every error names the offending field (``section.key``) and what is expected. The shipped example
``edge_monitor/defaults/agent.toml`` documents every key; ``edge-monitor commission`` writes the
``[friction]`` section.
"""

from __future__ import annotations

import dataclasses
import math
import tomllib
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Mapping

from joint_model.friction import DEFAULT_PARAMS, FrictionParams
from edge_monitor.features.segmentation import PlateauConfig


class ConfigError(ValueError):
    """A configuration value is missing, of the wrong type or out of range."""


@dataclass(frozen=True)
class WearConfig:
    """Wear estimation settings (ALGORITHMS.md §3)."""

    enabled: bool = True
    # "marginal": ξ ~ U(temperature range) marginalised for every N (unbiased within tolerance and an
    # honest std in the Monte Carlo study); "joint": §3's constrained NLS in [ξ, ϖ] for N ≥ 2, which is
    # biased low by 0.3–0.6 σ at the design speeds (docs/WEAR_ESTIMATION.md).
    method: str = "marginal"
    noise_std: float = 5.70e-3           # σ of a friction datum
    temperature_min: float = 30.0        # plausible lubricant temperature range of the site [°C]
    temperature_max: float = 50.0
    default_load_mean: float = 0.5       # μl when the controller sends no load estimate
    default_load_std: float = 0.1        # σl when the controller sends none
    critical: float = 35.0


@dataclass(frozen=True)
class KLConfig:
    """Distribution-domain detector settings (ALGORITHMS.md §4)."""

    enabled: bool = True
    n_nominal_cycles: int = 10
    n_grid: int = 512
    window: str = "cycle"                # "cycle" | "production"
    center: bool = True                  # compare densities of torque − cycle mean (load/gravity invariant)
    alpha: float = 1.45e-2               # w(v) = sech(β·v)·tanh(α·v)
    beta: float = 4.55e-2


@dataclass(frozen=True)
class DecisionConfig:
    """Sequential GLR decision layer settings (ALGORITHMS.md §5–6)."""

    enabled: bool = True
    n_nominal: int = 60
    density: str = "gce"                 # "gauss" | "kde" | "gce", for the scalar quantities
    # For the joint vector (d = 3) the GCE mixture of 60 points is neither sparse nor smooth (29 of
    # 60 points kept in the demo) and the windowed GLR then exceeds its χ² threshold on nominal data;
    # the KDE (Silverman) stays calibrated there. See docs/DETECTION.md.
    density_joint: str = "kde"
    # Per-test false-alarm probability of the asymptotic threshold. The windowed GLR takes a max over
    # candidate change times and the nominal density is learned from only 60 cycles, so the sequential
    # false-alarm rate is far higher than Pf. Measured ARL0 (tools/arl_study.py, docs/DETECTION.md):
    # Gaussian data 145 cycles at 1e-4; on surrogates of the agent's quantities at 1e-9: wear 2.9·10³,
    # log KL 1.0–1.1·10⁴; at 1e-11 ≥ 1.67·10⁴ for all three. The joint 3-vector (KDE) needs 1e-12 (1.1·10⁴).
    # These are the product defaults for ARL0 ≥ 10⁴ cycles.
    pf: float = 1e-11
    pf_joint: float = 1e-12
    window: int = 100
    gamma0: float = 0.6
    rho: float = 1.0
    quantities: tuple[str, ...] = ("wear", "kl_raw", "kl_weighted", "joint")
    # KL distances are positive and right-skewed (≈ log-normal); a location-shift GLR on them has a
    # short ARL0 (≈ 250 cycles for gamma-shaped data at the default Pf), so detectors watch log q.
    log_kl: bool = True


@dataclass(frozen=True)
class AgentConfig:
    robot: str = "robot1"
    rate_hz: float = 500.0
    joints: tuple[int, ...] | None = None      # None: every joint seen on the bus
    friction: FrictionParams = DEFAULT_PARAMS
    joint_friction: Mapping[int, FrictionParams] = field(default_factory=dict)
    segmentation: PlateauConfig = field(default_factory=PlateauConfig)
    wear: WearConfig = field(default_factory=WearConfig)
    kl: KLConfig = field(default_factory=KLConfig)
    decision: DecisionConfig = field(default_factory=DecisionConfig)
    queue_size: int = 65536                   # bounded CAN receive queue (frames)
    block_size: int = 4096                    # frames per processing block
    status_interval_s: float = 10.0           # periodic status line / health publication
    state_dir: str | None = None
    jsonl: str | None = None
    rerun: str = "off"
    zenoh: Mapping[str, Any] = field(default_factory=dict)

    def __post_init__(self) -> None:
        _validate(self)

    def friction_for(self, joint: int) -> FrictionParams:
        return self.joint_friction.get(joint, self.friction)


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
        if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
            raise ConfigError(f"{where}: expected a finite number, got {value!r}")
        return float(value)
    if isinstance(default, str) or (default is None and isinstance(value, str)):
        if not isinstance(value, str):
            raise ConfigError(f"{where}: expected a string, got {value!r}")
        return value
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
        names = ", ".join(f"{where}.{k}" for k in unknown)
        raise ConfigError(f"{names}: unknown key; known keys of [{where}]: {sorted(known)}")
    defaults = cls()
    return {key: _coerce(f"{where}.{key}", raw, getattr(defaults, key)) for key, raw in values.items()}


def _section(cls: type, values: Mapping[str, Any], where: str) -> Any:
    kwargs = _coerce_fields(cls, values, where)
    try:
        return cls(**kwargs)
    except ValueError as exc:
        raise ConfigError(str(exc)) from None


def _validate(cfg: AgentConfig) -> AgentConfig:
    checks = [
        (cfg.rate_hz > 0, "rate_hz: must be > 0"),
        (cfg.queue_size > 0, "queue_size: must be > 0"),
        (cfg.block_size > 0, "block_size: must be > 0"),
        (cfg.wear.noise_std > 0, "wear.noise_std: must be > 0"),
        (cfg.wear.method in ("marginal", "joint"), "wear.method: must be 'marginal' or 'joint'"),
        (cfg.wear.temperature_min < cfg.wear.temperature_max,
         "wear.temperature_min: must be below wear.temperature_max"),
        (cfg.wear.default_load_std >= 0, "wear.default_load_std: must be >= 0"),
        (cfg.kl.n_nominal_cycles >= 1, "kl.n_nominal_cycles: must be >= 1"),
        (cfg.kl.n_grid >= 16, "kl.n_grid: must be >= 16"),
        (cfg.kl.window in ("cycle", "production"), "kl.window: must be 'cycle' or 'production'"),
        (cfg.decision.n_nominal >= 2, "decision.n_nominal: must be >= 2"),
        (cfg.decision.density in ("gauss", "kde", "gce"), "decision.density: must be gauss, kde or gce"),
        (cfg.decision.density_joint in ("gauss", "kde", "gce"), "decision.density_joint: must be gauss, kde or gce"),
        (0 < cfg.decision.pf < 1, "decision.pf: the false-alarm probability must be in (0, 1)"),
        (0 < cfg.decision.pf_joint < 1, "decision.pf_joint: the false-alarm probability must be in (0, 1)"),
        (cfg.decision.window >= 1, "decision.window: must be >= 1"),
        (0 < cfg.decision.gamma0 < 1, "decision.gamma0: must be in (0, 1)"),
        (0.5 < cfg.decision.rho <= 1, "decision.rho: must be in (0.5, 1]"),
        (set(cfg.decision.quantities) <= {"wear", "kl_raw", "kl_weighted", "joint"},
         "decision.quantities: allowed are wear, kl_raw, kl_weighted, joint"),
        (cfg.joints is None or all(isinstance(j, int) and 0 <= j < 8 for j in cfg.joints),
         "joints: joint indices must be integers 0 … 7"),
    ]
    for ok, message in checks:
        if not ok:
            raise ConfigError(message)
    from edge_monitor.stats.densities import min_points
    for quantity in cfg.decision.quantities:
        density = cfg.decision.density_joint if quantity == "joint" else cfg.decision.density
        need = min_points(density, 3 if quantity == "joint" else 1)
        if cfg.decision.n_nominal < need:
            raise ConfigError(f"decision.n_nominal: {cfg.decision.n_nominal} cycles are too few for the "
                              f"'{density}' density of quantity '{quantity}'; use at least {need}")
    return cfg


def config_from_mapping(data: Mapping[str, Any]) -> AgentConfig:
    """Build a validated configuration from a parsed TOML document."""
    data = dict(data)
    kwargs: dict[str, Any] = {}
    sections = {"segmentation": PlateauConfig, "wear": WearConfig, "kl": KLConfig, "decision": DecisionConfig}
    for name, cls in sections.items():
        if name in data:
            kwargs[name] = _section(cls, data.pop(name), name)
    if "friction" in data:
        try:
            kwargs["friction"] = FrictionParams.from_mapping(data.pop("friction"), "friction")
        except ValueError as exc:
            raise ConfigError(str(exc)) from None
    if "joint" in data:
        joint_friction = {}
        for key, table in dict(data.pop("joint")).items():
            if not str(key).isdigit() or not 0 <= int(key) < 8:
                raise ConfigError(f"joint.{key}: joint index must be 0 … 7")
            try:
                joint_friction[int(key)] = FrictionParams.from_mapping(table.get("friction", {}),
                                                                       f"joint.{key}.friction")
            except ValueError as exc:
                raise ConfigError(str(exc)) from None
        kwargs["joint_friction"] = joint_friction
    if "zenoh" in data:
        if not isinstance(data["zenoh"], Mapping):
            raise ConfigError("zenoh: expected a table")
        kwargs["zenoh"] = dict(data.pop("zenoh"))
    kwargs.update(_coerce_fields(AgentConfig, data, "config", _TOP_LEVEL_KEYS))
    try:
        return AgentConfig(**kwargs)
    except ValueError as exc:
        raise ConfigError(str(exc)) from None


#: Plain keys at the top of the TOML file (the structured fields have tables of their own).
_TOP_LEVEL_KEYS = frozenset(f.name for f in dataclasses.fields(AgentConfig)) - {
    "friction", "joint_friction", "segmentation", "wear", "kl", "decision", "zenoh"}


def load_config(path: str | Path | None) -> AgentConfig:
    """Load a TOML config file; ``None`` gives the embedded defaults."""
    if path is None:
        return AgentConfig()
    p = Path(path)
    try:
        data = tomllib.loads(p.read_text(encoding="utf-8"))
    except FileNotFoundError:
        raise ConfigError(f"config file {p} not found; pass an existing TOML file "
                          f"(example: edge_monitor/defaults/agent.toml)") from None
    except tomllib.TOMLDecodeError as exc:
        raise ConfigError(f"config file {p}: invalid TOML: {exc}") from None
    return config_from_mapping(data)


def with_overrides(cfg: AgentConfig, **overrides: Any) -> AgentConfig:
    """Apply command-line overrides (``None`` means: keep the config value)."""
    changes = {k: v for k, v in overrides.items() if v is not None}
    return dataclasses.replace(cfg, **changes) if changes else cfg
