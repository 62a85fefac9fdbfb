"""The agent's configuration: one frozen dataclass composed of the components' own configs.

Every component validates its own section once, in its dataclass (:class:`PlateauConfig`,
:class:`WearConfig`, :class:`KLConfig`, :class:`DecisionConfig`); this class checks the top-level
keys. Reading TOML and command-line overrides is :mod:`edge_monitor.config`. A bad value raises
:class:`~edge_monitor.errors.ConfigError` naming the field.
"""

from __future__ import annotations

import math
import re
from dataclasses import asdict, dataclass, field, replace
from typing import TYPE_CHECKING, Any, Mapping

from edge_monitor.errors import require
from edge_monitor.features.joint_model_learning import ModelConfig
from edge_monitor.features.kl_monitor import KLConfig
from edge_monitor.features.prognosis import PrognosisConfig
from edge_monitor.features.segmentation import PlateauConfig
from edge_monitor.features.wear import WearConfig
from edge_monitor.pipeline.decision_config import (
    CALIBRATION_KEYS,
    SCHEDULE_KEYS,
    DecisionConfig,
    learned_settings,
)
from edge_monitor.pipeline.fault_grouping import AlarmConfig
from edge_monitor.sinks.acknowledge import AcknowledgeConfig
from edge_monitor.sinks.jsonl import Rotation
from edge_monitor.sinks.maintenance import MaintenanceConfig
from joint_model import DEFAULT_PARAMS, FrictionParams
from protocol.frames import MAX_JOINTS

if TYPE_CHECKING:
    from protocol.signal_mapping import SignalMapping

#: Bounds of the sizes a config may ask for (memory and time stay bounded whatever the file says).
MAX_QUEUE = 10_000_000          # frames
MAX_BLOCK = 1_000_000           # frames per processing block
#: What a restored component learned with another configuration becomes: relearned, or kept.
ON_CONFIG_CHANGE = ("relearn", "keep")
#: Robot names: Zenoh key segment and file-name safe.
ROBOT_NAME = re.compile(r"^[A-Za-z0-9_.-]{1,64}$")
#: Decision settings a restored joint takes from the current config even under "keep": they are not learned.
LIVE_DECISION_KEYS = SCHEDULE_KEYS + CALIBRATION_KEYS


def _learned(section: str, saved: Any) -> Any:
    """What of a saved fingerprint ``section`` was learned (a decision one saved with settings that are
    not learned, by an older version, compares without them)."""
    return learned_settings(saved) if section == "decision" and isinstance(saved, dict) else saved


@dataclass(frozen=True)
class AgentConfig:
    """Everything that configures an agent (see ``edge_monitor/defaults/agent.toml`` for every key)."""

    robot: str = "robot1"
    rate_hz: float = 500.0
    joints: tuple[int, ...] | None = None      # None: every joint seen on the bus
    friction: FrictionParams = DEFAULT_PARAMS
    joint_friction: Mapping[int, FrictionParams] = field(default_factory=dict)
    joint_critical_wear: Mapping[int, float] = field(default_factory=dict)    # [joint.N] critical_wear
    segmentation: PlateauConfig = field(default_factory=PlateauConfig)
    model: ModelConfig = field(default_factory=ModelConfig)
    wear: WearConfig = field(default_factory=WearConfig)
    kl: KLConfig = field(default_factory=KLConfig)
    decision: DecisionConfig = field(default_factory=DecisionConfig)
    prognosis: PrognosisConfig = field(default_factory=PrognosisConfig)
    alarms: AlarmConfig = field(default_factory=AlarmConfig)
    maintenance: MaintenanceConfig = field(default_factory=MaintenanceConfig)
    acknowledge: AcknowledgeConfig = field(default_factory=AcknowledgeConfig)
    on_config_change: str = "relearn"          # relearn | keep (what was learned with another config)
    queue_size: int = 65536                    # bounded CAN receive queue [frames]
    block_size: int = 4096                     # frames per processing block
    status_interval_s: float = 10.0            # periodic status line / health publication [s]
    data_timeout_s: float = 60.0               # no sample for this long: health data_flowing false (0: never)
    state_dir: str | None = None
    jsonl: str | None = None
    jsonl_max_bytes: int = 64 << 20            # rotate the JSONL file before it passes this size (0: never)
    jsonl_keep: int = 5                        # rotated JSONL files kept: PATH.1 … PATH.<keep>
    rerun: str = "off"
    zenoh: Mapping[str, Any] = field(default_factory=dict)

    def __post_init__(self) -> None:
        require(isinstance(self.robot, str) and bool(ROBOT_NAME.match(self.robot)), "robot",
                f"{self.robot!r}: use 1 … 64 letters, digits, '_', '-' or '.' (it is a Zenoh key segment)")
        require(math.isfinite(self.rate_hz) and 1 <= self.rate_hz <= 100_000, "rate_hz",
                f"must be 1 … 100000 Hz, got {self.rate_hz}")
        if self.joints is not None:
            require(isinstance(self.joints, tuple | list), "joints",
                    f"expected a list of joint indices such as [0, 1, 2], got {self.joints!r}")
            require(len(self.joints) > 0, "joints",
                    "an empty list monitors nothing; omit the key to monitor every joint")
            require(all(isinstance(j, int) and not isinstance(j, bool) and 0 <= j < MAX_JOINTS for j in self.joints),
                    "joints", f"joint indices must be integers 0 … {MAX_JOINTS - 1}, got {list(self.joints)}")
        require(all(0 <= j < MAX_JOINTS for j in (*self.joint_friction, *self.joint_critical_wear)), "joint",
                f"joint indices must be 0 … {MAX_JOINTS - 1}")
        require(all(math.isfinite(w) and 0 < w <= 100 for w in self.joint_critical_wear.values()),
                "joint.N.critical_wear", f"must be in (0, 100], got {dict(self.joint_critical_wear)}")
        require(self.on_config_change in ON_CONFIG_CHANGE, "on_config_change",
                f"must be one of {ON_CONFIG_CHANGE}, got {self.on_config_change!r}")
        require(1 <= self.queue_size <= MAX_QUEUE, "queue_size",
                f"must be 1 … {MAX_QUEUE} frames, got {self.queue_size}")
        require(1 <= self.block_size <= MAX_BLOCK, "block_size",
                f"must be 1 … {MAX_BLOCK} frames, got {self.block_size}")
        require(math.isfinite(self.status_interval_s) and 0.1 <= self.status_interval_s <= 86_400,
                "status_interval_s", f"must be 0.1 … 86400 s, got {self.status_interval_s}")
        require(math.isfinite(self.data_timeout_s) and (self.data_timeout_s == 0 or 1 <= self.data_timeout_s <= 86_400),
                "data_timeout_s", f"must be 0 (never) or 1 … 86400 s, got {self.data_timeout_s}")
        self.jsonl_rotation()           # validates jsonl_max_bytes and jsonl_keep

    def jsonl_rotation(self) -> Rotation:
        """The JSONL file's rotation settings."""
        return Rotation(self.jsonl_max_bytes, self.jsonl_keep)

    def friction_for(self, joint: int) -> FrictionParams:
        """The friction parameters of ``joint``: its own table if configured, else the common one."""
        return self.joint_friction.get(joint, self.friction)

    def critical_wear_for(self, joint: int) -> float:
        """The critical wear of ``joint``: its ``[joint.N] critical_wear`` if configured, else ``[wear] critical``."""
        return float(self.joint_critical_wear.get(joint, self.wear.critical))

    def fingerprint(self, joint: int | None = None) -> dict[str, Any]:
        """The settings learned state depends on, by section (compared when a state is restored)."""
        friction = self.friction if joint is None else self.friction_for(joint)
        return {"segmentation": self.segmentation.fingerprint(), "model": self.model.fingerprint(),
                "wear": self.wear.fingerprint(),
                "kl": self.kl.fingerprint(), "decision": self.decision.fingerprint(),
                "friction": asdict(friction)}

    def with_learned(self, joint: int, saved: dict[str, Any]) -> tuple["AgentConfig", list[str]]:
        """``on_config_change = "keep"``: this config with the sections ``saved`` (a :meth:`fingerprint`
        of the config ``joint``'s models were learned with) where they differ; and the names of those
        sections. Sections that cannot be rebuilt from ``saved`` stay as they are."""
        current = self.fingerprint(joint)
        builders: dict[str, Any] = {
            "segmentation": lambda d: PlateauConfig(**{**d, "speeds": tuple(d["speeds"])}),
            "wear": lambda d: WearConfig(**d, enabled=self.wear.enabled, critical=self.wear.critical),
            "kl": lambda d: KLConfig(**d, enabled=self.kl.enabled),
            "decision": lambda d: DecisionConfig(**{**{k: getattr(self.decision, k) for k in LIVE_DECISION_KEYS},
                                                   **learned_settings(d), "quantities": tuple(d["quantities"])}),
        }
        changes: dict[str, Any] = {}
        for name, build in builders.items():
            if name in saved and _learned(name, saved[name]) != current[name]:
                try:
                    changes[name] = build(saved[name])
                except (TypeError, ValueError, KeyError, AttributeError):   # a damaged section
                    continue
        if "friction" in saved and saved["friction"] != current["friction"]:
            try:
                changes["joint_friction"] = {**self.joint_friction, joint: FrictionParams(**saved["friction"])}
            except (TypeError, ValueError):
                pass
        kept = sorted("friction" if k == "joint_friction" else k for k in changes)
        return (replace(self, **changes) if changes else self), kept


def config_for(config: AgentConfig, mapping: SignalMapping) -> AgentConfig:
    """The agent config a mapping file needs: its rate (the tick rate the samples' times are converted
    to; a mapping that states ``rate_hz`` overrides the config's) and (cycles from a trigger)
    the designed speeds as the plateau levels (the trigger marks the cycle, not the levels); and, where neither
    ``joints`` nor ``[decision] joints_per_robot`` is stated, the mapped joints as the ones the robot's false-alarm
    budget is split over (a 3-joint robot's detectors get a third of the budget each, not a sixth)."""
    out = config
    if out.joints is None and out.decision.joints_per_robot is None:
        out = replace(out, decision=replace(out.decision, joints_per_robot=len(mapping.joints)))
    if mapping.rate_hz is not None:
        out = replace(out, rate_hz=mapping.rate_hz)
    if mapping.cycles.source == "trigger" and not out.segmentation.speeds:
        out = replace(out, segmentation=replace(out.segmentation, speeds=mapping.cycles.speeds))
    return out
