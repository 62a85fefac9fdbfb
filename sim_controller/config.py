"""Simulator configuration (``SimConfig``) and parsers for the command-line value formats.

Every parser raises :class:`SimConfigError` (a ``ValueError``) whose message names the field and
says what is expected. Units: speeds rad/s (motor side), torques dimensionless (fraction of the
joint's maximum torque), temperatures °C, times s, rates Hz.
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any, Callable, Sequence

from joint_model import DEFAULT_SPEED_LEVELS, FRICTION_NOISE_STD, FrictionParams
from protocol.frames import MAX_JOINTS
from sim_controller.faults import FaultSpec
from sim_controller.timeline import (
    CONDITIONS,
    PlantConditions,
    PlantEvent,
    TimelineError,
    check_condition,
    check_order,
    conditions_at,
    stop_before,
)
from sim_controller.wear_scenarios import WearEvent, WearProfile, parse_wear_law, parse_wear_ramp

#: Default friction speed levels [rad/s] (defined once, in joint_model).
DEFAULT_SPEEDS = DEFAULT_SPEED_LEVELS
#: Largest |speed| the MotorState frame can carry [rad/s].
MAX_SPEED = 600.0
#: The latest start time a recording may have [s since 1970]: the year 3000 (BLF and ASC headers keep a date).
MAX_START_TIME = 32_503_680_000.0


class SimConfigError(ValueError):
    """Invalid simulator configuration; the message names the field and the fix."""


@dataclass(frozen=True)
class JointOverride:
    """Per-joint settings from a scenario file (``None`` = keep the default)."""

    friction: FrictionParams | None = None
    load_sign: float | None = None


@dataclass(frozen=True)
class SimConfig:
    """Everything that determines a simulation run (with ``seed``, the output is reproducible).

    Speeds rad/s, torques dimensionless, temperatures °C, durations s.
    """

    joints: int = 6
    rate: float = 500.0
    cycles: int = 10
    seed: int = 0
    speeds: tuple[float, ...] = DEFAULT_SPEEDS
    # test cycle
    plateau_time: float = 1.1          # constant-speed time per direction and level [s] (incl. settle)
    acceleration: float = 2000.0       # motor-side reference acceleration [rad/s²]
    pause_time: float = 0.2            # segment-0 pause after each level [s]
    p2p_delay: tuple[float, float] = (0.025, 0.075)   # production point-to-point delay range [s]
    production_speed: float = 150.0    # production move speed [rad/s]
    # friction
    friction_model_error: float = FRICTION_NOISE_STD   # σm, per cycle & level offset std
    variation: float | None = None     # relative ± spread of friction parameters; None: 0 for 1 joint, 0.08 otherwise
    friction: FrictionParams = FrictionParams()
    # measurement
    torque_noise: float = 2e-3         # per-sample torque noise std (dimensionless)
    speed_noise: float = 0.02          # per-sample speed noise std [rad/s]
    # load
    load_range: tuple[float, float] = (0.3, 0.7)   # |τl| uniform per cycle
    load_std: float = 0.1              # σl of the controller's estimate
    payload_error: float = 0.0         # relative error of the controller's payload mass: its load estimate
                                       # (and gravity feedforward) is (1 + payload_error)·τl + N(0, σl²)
    # temperature
    temperature_range: tuple[float, float] | None = None   # per-cycle uniform draw instead of the thermal model
    ambient: float = 30.0
    start_temperature: float = 30.0
    min_temperature: float = 30.0
    thermal_time_constant: float = 3.04 * 3600.0
    time_acceleration: float = 1.0
    heating: float = 4.0               # steady-state rise per unit mean friction power [°C / (torque·rad/s)]
    # wear (one profile per joint; missing joints have no wear)
    wear: tuple[WearProfile, ...] = ()
    # faults, restarts
    faults: FaultSpec = FaultSpec()
    # output
    start_time: float = 0.0            # timestamp offset of tick 0 in record mode [s] (≤ MAX_START_TIME)
    block_time: float = 0.5            # length of the frame blocks yielded [s]
    joint_overrides: tuple[JointOverride | None, ...] = ()
    # plant changes over the run (sim_controller.timeline): events in increasing cycle order
    timeline: tuple[PlantEvent, ...] = ()

    def __post_init__(self) -> None:
        object.__setattr__(self, "timeline", tuple(self.timeline))
        validate(self)

    def with_(self, **changes: Any) -> "SimConfig":
        """Copy with changes (validated)."""
        return replace(self, **changes)

    def wear_profile(self, joint: int) -> WearProfile:
        return self.wear[joint] if joint < len(self.wear) else WearProfile()

    def conditions(self, cycle: int) -> PlantConditions:
        """Load range, ambient, payload error and σl in effect at ``cycle`` (the timeline applied)."""
        base = PlantConditions(self.load_range, self.ambient, self.payload_error, self.load_std)
        return conditions_at(base, self.timeline, cycle) if self.timeline else base

    def stop_hours(self, cycle: int) -> float:
        """Hours the robot stands still before ``cycle`` (0.0: none)."""
        return stop_before(self.timeline, cycle) if self.timeline else 0.0

    def effective_variation(self) -> float:
        if self.variation is not None:
            return self.variation
        return 0.0 if self.joints == 1 else 0.08


def _require(cond: bool, field_name: str, message: str) -> None:
    if not cond:
        raise SimConfigError(f"{field_name}: {message}")


def _finite(value: float) -> bool:
    return isinstance(value, (int, float)) and math.isfinite(value)


def validate(c: SimConfig) -> None:
    """Check ranges; raise :class:`SimConfigError` naming the first bad field."""
    _require(isinstance(c.joints, int) and 1 <= c.joints <= MAX_JOINTS, "joints",
             f"must be an integer 1 … {MAX_JOINTS}, got {c.joints!r}")
    _require(_finite(c.rate) and 50.0 <= c.rate <= 5000.0, "rate", f"must be 50 … 5000 Hz, got {c.rate!r}")
    _require(isinstance(c.cycles, int) and c.cycles >= 1, "cycles", f"must be an integer ≥ 1, got {c.cycles!r}")
    _require(isinstance(c.seed, int) and c.seed >= 0, "seed", f"must be an integer ≥ 0, got {c.seed!r}")
    _require(1 <= len(c.speeds) <= 64, "speeds", f"need 1 … 64 speed levels, got {len(c.speeds)}")
    for v in c.speeds:
        _require(_finite(v) and 0.0 < v <= MAX_SPEED, "speeds",
                 f"each speed must be in (0, {MAX_SPEED}] rad/s, got {v!r}")
    _require(len(set(c.speeds)) == len(c.speeds), "speeds",
             f"each speed level once (the agent tells the test cycle's plateaus apart by speed), got {c.speeds!r}")
    _require(_finite(c.plateau_time) and 0.05 <= c.plateau_time <= 60.0, "plateau_time",
             f"must be 0.05 … 60 s, got {c.plateau_time!r}")
    _require(_finite(c.acceleration) and c.acceleration > 0, "acceleration",
             f"must be > 0 rad/s², got {c.acceleration!r}")
    _require(_finite(c.pause_time) and 0.0 <= c.pause_time <= 60.0, "pause_time",
             f"must be 0 … 60 s, got {c.pause_time!r}")
    lo, hi = c.p2p_delay
    _require(_finite(lo) and _finite(hi) and 0.0 <= lo <= hi <= 10.0, "p2p_delay",
             f"need 0 ≤ LOW ≤ HIGH ≤ 10 s, got {lo!r}:{hi!r}")
    _require(_finite(c.production_speed) and 0.0 < c.production_speed <= MAX_SPEED, "production_speed",
             f"must be in (0, {MAX_SPEED}] rad/s, got {c.production_speed!r}")
    _require(_finite(c.friction_model_error) and 0.0 <= c.friction_model_error <= 0.1, "friction_model_error",
             f"must be 0 … 0.1, got {c.friction_model_error!r}")
    if c.variation is not None:
        _require(_finite(c.variation) and 0.0 <= c.variation <= 0.5, "vary",
                 f"relative variation must be 0 … 0.5, got {c.variation!r}")
    _require(_finite(c.torque_noise) and 0.0 <= c.torque_noise <= 0.1, "torque_noise",
             f"must be 0 … 0.1, got {c.torque_noise!r}")
    _require(_finite(c.speed_noise) and 0.0 <= c.speed_noise <= 5.0, "speed_noise",
             f"must be 0 … 5 rad/s, got {c.speed_noise!r}")
    for name in CONDITIONS:
        try:
            check_condition(name, getattr(c, name), "")
        except TimelineError as exc:
            raise SimConfigError(str(exc)) from None
    if c.temperature_range is not None:
        lo, hi = c.temperature_range
        _require(_finite(lo) and _finite(hi) and lo <= hi, "temperature_range", f"need LOW ≤ HIGH, got {lo!r}:{hi!r}")
        _require(-40.0 <= lo and hi <= 150.0, "temperature_range", f"must lie within −40 … 150 °C, got {lo!r}:{hi!r}")
    for name in ("start_temperature", "min_temperature"):
        value = getattr(c, name)
        _require(_finite(value) and -40.0 <= value <= 150.0, name, f"must be −40 … 150 °C, got {value!r}")
    _require(_finite(c.thermal_time_constant) and c.thermal_time_constant > 0, "thermal_time_constant",
             f"must be > 0 s, got {c.thermal_time_constant!r}")
    _require(_finite(c.time_acceleration) and 0 < c.time_acceleration <= 1e6, "time_acceleration",
             f"must be in (0, 1e6], got {c.time_acceleration!r}")
    _require(_finite(c.heating) and c.heating >= 0, "heating", f"must be ≥ 0 °C per unit power, got {c.heating!r}")
    _require(len(c.wear) <= c.joints, "wear", f"{len(c.wear)} wear profiles for {c.joints} joints")
    _require(_finite(c.start_time) and 0 <= c.start_time <= MAX_START_TIME, "start_time",
             f"must be 0 … {MAX_START_TIME:.0f} s (the year 3000: log formats keep a calendar date), "
             f"got {c.start_time!r}")
    _require(_finite(c.block_time) and 0.01 <= c.block_time <= 60, "block_time",
             f"must be 0.01 … 60 s, got {c.block_time!r}")
    _require(len(c.joint_overrides) <= c.joints, "joint_overrides",
             f"{len(c.joint_overrides)} overrides for {c.joints} joints")
    for i, event in enumerate(c.timeline):
        _require(isinstance(event, PlantEvent), f"timeline[{i}]", f"expected a PlantEvent, got {event!r}")
    try:
        check_order(c.timeline, "timeline")
    except TimelineError as exc:
        raise SimConfigError(str(exc)) from None


# ---------------------------------------------------------------------------------------------
# parsers for command-line value formats


def parse_float(text: str, field_name: str) -> float:
    try:
        value = float(text)
    except (TypeError, ValueError):
        raise SimConfigError(f"{field_name}: expected a number, got {text!r}") from None
    if not math.isfinite(value):
        raise SimConfigError(f"{field_name}: must be finite, got {text!r}")
    return value


def parse_range(text: str, field_name: str) -> tuple[float, float]:
    """``LOW:HIGH`` → (low, high) with LOW ≤ HIGH."""
    parts = text.split(":")
    if len(parts) != 2:
        raise SimConfigError(f"{field_name}: expected LOW:HIGH, got {text!r}")
    low, high = (parse_float(p, field_name) for p in parts)
    if low > high:
        raise SimConfigError(f"{field_name}: LOW must be ≤ HIGH, got {text!r}")
    return low, high


def parse_speeds(text: str) -> tuple[float, ...]:
    """``V1,V2,...`` → speeds [rad/s]."""
    items = [s for s in text.split(",") if s.strip()]
    if not items:
        raise SimConfigError(f"speeds: expected V1,V2,... in rad/s, got {text!r}")
    return tuple(parse_float(s.strip(), "speeds") for s in items)


def load_speeds_file(path: str | Path) -> tuple[float, ...]:
    """Speeds from the JSON of ``edge-monitor design`` (``{"speeds": [...]}``)."""
    try:
        doc = json.loads(Path(path).read_text(encoding="utf-8"))
    except OSError as exc:
        raise SimConfigError(f"speeds_from: cannot read {path}: {exc.strerror or exc}") from None
    except UnicodeDecodeError as exc:
        raise SimConfigError(f"speeds_from: {path} is not UTF-8 text ({exc.reason} at byte {exc.start}): is it "
                             "the JSON of edge-monitor design?") from None
    except json.JSONDecodeError as exc:
        raise SimConfigError(f"speeds_from: {path} is not JSON: {exc}") from None
    if not isinstance(doc, dict) or not isinstance(doc.get("speeds"), list):
        raise SimConfigError(f"speeds_from: {path} needs a \"speeds\" list (the JSON of edge-monitor design)")
    try:
        return tuple(float(v) for v in doc["speeds"])
    except (TypeError, ValueError):
        raise SimConfigError(f"speeds_from: {path}: \"speeds\" must be numbers") from None


def wear_profiles_from_ramps(specs: Sequence[str], joints: int) -> tuple[WearProfile, ...]:
    """Apply ``--wear-ramp JOINT:START:END:FROM:TO`` flags (JOINT 0-based or ``all``)."""
    return _wear_profiles(specs, joints, parse_wear_ramp, "wear_ramp")


def wear_profiles_from_laws(specs: Sequence[str], joints: int) -> tuple[WearProfile, ...]:
    """Apply ``--wear-law JOINT:KIND:KEY=VALUE,...`` flags (JOINT 0-based or ``all``), in order."""
    return _wear_profiles(specs, joints, parse_wear_law, "wear_law")


def _wear_profiles(specs: Sequence[str], joints: int, parse: Callable[[str], tuple[int | str, WearEvent]],
                   option: str) -> tuple[WearProfile, ...]:
    events: list[list[WearEvent]] = [[] for _ in range(joints)]
    for spec in specs:
        target, event = parse(spec)
        if target == "all":
            for lst in events:
                lst.append(event)
        else:
            if not 0 <= int(target) < joints:
                raise SimConfigError(f"{option}: unknown joint {target} in {spec!r}; "
                                     f"joints are 0 … {joints - 1} or 'all'")
            events[int(target)].append(event)
    return tuple(WearProfile(events=tuple(e)) for e in events)


def merge_wear(base: Sequence[WearProfile], extra: Sequence[WearProfile], joints: int) -> tuple[WearProfile, ...]:
    """Per joint, events of ``base`` followed by those of ``extra``."""
    out = []
    for j in range(joints):
        a = base[j] if j < len(base) else WearProfile()
        b = extra[j] if j < len(extra) else WearProfile()
        out.append(WearProfile(initial=a.initial if a.initial else b.initial, events=a.events + b.events))
    return tuple(out)


__all__ = [
    "DEFAULT_SPEEDS", "JointOverride", "SimConfig", "SimConfigError",
    "load_speeds_file", "merge_wear", "parse_float", "parse_range", "parse_speeds", "wear_profiles_from_laws",
    "wear_profiles_from_ramps",
]
