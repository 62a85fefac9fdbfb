"""The ``[decision]`` table: which registered quantities a joint's detectors watch, how they learn, and the
false-alarm budget their thresholds are derived for (docs/DETECTION.md). Validated once, here; the
detectors themselves are :class:`~edge_monitor.pipeline.detectors.DetectorBank`.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import asdict, dataclass, field
from typing import Any

from edge_monitor.errors import ConfigError, require
from edge_monitor.features.registry import LOG_SCALE, QUANTITIES
from edge_monitor.pipeline.healthy_drift import (
    HEALTHY_DRIFT,
    LEARNED_SD_PRIOR_FRICTION,
    STEADY_DRIFT,
    STEADY_DRIFT_JOINT,
    STEADY_WANDER,
    TEMPERATURE_SLACK,
    WARM_UP_LAW,
    WARM_UP_LAW_FRICTION,
    healthy_drift,
    learned_sd_prior,
    steady_wander,
    temperature_slack,
    warm_up_law,
)
from edge_monitor.pipeline.thermal_settling import SettlingConfig
from edge_monitor.stats.calibration import CALIBRATE_AT, MAX_ARL0, MIN_ARL0, CalibrationBudget
from edge_monitor.stats.detector_config import (
    DEFAULT_NOMINAL,
    DEFAULT_STEADY_NOMINAL,
    DEFAULT_WINDOW,
    DetectorConfig,
    without_default_steady,
)

#: Settings that are not what a detector learned — when the steady stage starts, and the false-alarm
#: target its threshold is derived for (a changed target is re-derived on the same nominal,
#: :meth:`DetectorBank.retarget`): not in the fingerprint (a saved state stays valid when they change),
#: and kept from the current config on "keep".
SCHEDULE_KEYS = ("steady_relearn", "settling_window", "settling_max_rate", "warm_up_hold", "warm_up_hold_margin",
                 "temperature_slack", "pause_hold_cycles", "pause_hold_min_h",
                 "false_alarms_per_robot", "budget_period", "cycles_per_day", "joints_per_robot", "arl0_cycles")

#: Where the calibrations simulate the detectors (the point, the healthy drift after learning, the wander): not
#: what a detector learned either, so not in the fingerprint; a saved nominal's threshold is re-derived for the
#: current ones (``SequentialDetector.from_state``), and "keep" keeps the current ones.
CALIBRATION_KEYS = ("calibrate_at", "healthy_drift", "warm_up_law", "warm_up_law_friction", "steady_calibrate_at",
                    "steady_drift", "steady_drift_joint", "steady_wander")

#: Learned settings each detector's own fingerprint carries where they apply (a joint without motor temperature's
#: sd prior): not in the decision fingerprint, so that the states of other joints stay valid when they change.
PER_DETECTOR_KEYS = ("learned_sd_prior_friction",)

#: The periods a false-alarm budget may be stated per [days].
BUDGET_PERIODS: dict[str, float] = {"day": 1.0, "week": 7.0, "month": 365.25 / 12, "year": 365.25}
#: Test cycles a day the thresholds are derived for until the agent has measured its own rate.
DEFAULT_CYCLES_PER_DAY = 300.0
#: Joints the robot's budget is split over unless the config or its mapping file lists the joints (a six-axis arm).
DEFAULT_JOINTS_PER_ROBOT = 6
MAX_JOINTS_PER_ROBOT = 64


@dataclass(frozen=True)
class DecisionConfig:
    """Sequential GLR decision layer settings (the ``[decision]`` table), validated once, here.

    False alarms are stated per robot: ``false_alarms_per_robot`` per ``budget_period`` (day, week,
    month or year; default one a year), split evenly (Bonferroni) over the robot's detectors —
    ``joints_per_robot`` × the watched quantities — at ``cycles_per_day`` test cycles a day; expert
    option: ``arl0_cycles``, the mean run length to a false alarm of each detector [cycles], directly.
    Every detector calibrates its threshold for :attr:`arl0` at the end of learning (docs/DETECTION.md).
    ``pf``/``pf_joint`` (expert option) instead set the per-test false-alarm probability of the asymptotic threshold of
    the scalar / vector quantities. ``density`` applies to scalar quantities, ``density_joint`` to the
    vector ones: a GCE mixture of 60 points in 3-d is neither sparse nor smooth, the KDE is.
    ``temperature_slack`` (input → the fleet's law [mean, sd] of a [σ/√°C]): while the joint's temperature is
    d °C outside the span a detector's nominal was learned in, it tests its value less its joint's learned
    a·√d nominal standard deviations per input (:mod:`~edge_monitor.pipeline.temperature_slack`);
    ``pause_hold_cycles``: after a pause of at least ``pause_hold_min_h`` [h] in the samples the KL and
    joint-vector detectors hold for that many cycles (the KL temperature compensation settles);
    ``warm_up_hold`` (quantities) makes their detectors hold instead (warm-up: warmer than that span by more
    than ``warm_up_hold_margin`` [°C], or colder; steady: colder).
    ``calibrate_at``: where the calibration simulates each warm-up detector (default ``"healthy_drift"``: a fleet
    whose joints drift as ``healthy_drift`` (input → (mean, sd) [σ]) says, beyond the temperature slack and the
    learning error; a scalar detector of an input ``warm_up_law`` lists (input → (mean, sd, spread, spread sd)
    [learned σ]) is drawn from that law in its nominal's learned units instead, learning error included — on a
    joint whose controller sends no motor temperature (its detectors follow the friction's lubricant temperature)
    from ``warm_up_law_friction`` where that lists the input, and where it lists one of the joint vector's inputs
    every axis of that vector from its law (``warm_up_law_friction``'s, else ``warm_up_law``'s; without the wander;
    an axis neither lists keeps its learning error and ``healthy_drift``); there too the warm-up
    nominal's learned sd of each input ``learned_sd_prior_friction`` lists (input → (k, sd)) is shrunk towards sd
    by k pseudo-values);
    ``"boundary"``: every joint at the drift allowance, a bound; ``"nominal"``: no drift).
    ``steady_relearn``: once the joint's motor temperature has settled (``settling_window`` [cycles],
    ``settling_max_rate`` [°C per cycle]: :mod:`~edge_monitor.pipeline.thermal_settling`) every detector
    learns its nominal again, from ``steady_nominal`` cycles with the ``steady_density`` family after a
    ``steady_transform`` ("yeo-johnson" or "none") learned from the same values — of every scalar
    detector, and of the joint vector's inputs watched as logs — and calibrates it at
    ``steady_calibrate_at``, for the drift ``steady_drift`` (scalars) or ``steady_drift_joint`` (the joint
    vector's inputs) and the wander ``steady_wander`` (docs/DETECTION.md, "Two stages").
    """

    enabled: bool = True
    n_nominal: int = DEFAULT_NOMINAL
    density: str = "gauss"
    density_joint: str = "gauss"
    false_alarms_per_robot: float = 1.0
    budget_period: str = "year"
    cycles_per_day: float = DEFAULT_CYCLES_PER_DAY
    joints_per_robot: int | None = None     # None: not stated (the listed or mapped joints, else 6)
    arl0_cycles: float | None = None
    pf: float | None = None
    pf_joint: float | None = None
    window: int = DEFAULT_WINDOW
    gamma0: float = 0.6
    rho: float = 1.0
    quantities: tuple[str, ...] = tuple(QUANTITIES)
    log_scale: bool = True
    direction: str = "increase"
    allowance: float = 0.75
    clip_sigma: float = 3.0
    calibration_draws: int = CalibrationBudget().draws
    calibration_steps: int = CalibrationBudget().max_steps
    calibrate_at: str = "healthy_drift"
    healthy_drift: Mapping[str, tuple[float, float]] = field(default_factory=lambda: dict(HEALTHY_DRIFT))
    warm_up_law: Mapping[str, tuple[float, ...]] = field(default_factory=lambda: dict(WARM_UP_LAW))
    warm_up_law_friction: Mapping[str, tuple[float, ...]] = field(default_factory=lambda: dict(WARM_UP_LAW_FRICTION))
    learned_sd_prior_friction: Mapping[str, tuple[float, float]] = field(
        default_factory=lambda: dict(LEARNED_SD_PRIOR_FRICTION))
    steady_relearn: bool = True
    steady_calibrate_at: str = "healthy_drift"
    steady_drift: Mapping[str, tuple[float, float]] = field(default_factory=lambda: dict(STEADY_DRIFT))
    steady_drift_joint: Mapping[str, tuple[float, float]] = field(default_factory=lambda: dict(STEADY_DRIFT_JOINT))
    steady_wander: Mapping[str, float] = field(default_factory=lambda: dict(STEADY_WANDER))
    steady_nominal: int = DEFAULT_STEADY_NOMINAL
    steady_density: str = "gauss"
    steady_transform: str = "yeo-johnson"
    steady_simulate_from: str = "model"
    settling_window: int = SettlingConfig().window
    settling_max_rate: float = SettlingConfig().max_rate
    warm_up_hold: tuple[str, ...] = ()
    warm_up_hold_margin: float = 6.0
    temperature_slack: Mapping[str, tuple[float, float]] = field(default_factory=lambda: dict(TEMPERATURE_SLACK))
    pause_hold_cycles: int = 5
    pause_hold_min_h: float = 1.0

    @property
    def settling(self) -> SettlingConfig:
        return SettlingConfig(window=self.settling_window, max_rate=self.settling_max_rate)

    @property
    def detectors_per_robot(self) -> int:
        """How many detectors the robot's false-alarm budget is split over."""
        return self.detectors_for()

    def detectors_for(self, joints: int | None = None) -> int:
        """The detectors of a robot of ``joints`` joints (default :attr:`budget_joints`)."""
        return (self.budget_joints if joints is None else joints) * len(self.quantities)

    @property
    def budget_joints(self) -> int:
        """The joints the robot's budget is split over: ``joints_per_robot``, or 6 where it is not stated."""
        return DEFAULT_JOINTS_PER_ROBOT if self.joints_per_robot is None else self.joints_per_robot

    @property
    def arl0(self) -> float:
        """The mean run length to false alarm per detector [cycles] the thresholds are calibrated for."""
        return self.arl0_for(self.cycles_per_day)

    def arl0_for(self, cycles_per_day: float, joints: int | None = None) -> float:
        """:attr:`arl0` at ``cycles_per_day`` test cycles a day, the budget split over ``joints`` joints
        (default :attr:`budget_joints`; ``arl0_cycles`` if given: fixed)."""
        if self.arl0_cycles is not None:
            return float(self.arl0_cycles)
        days = BUDGET_PERIODS[self.budget_period]
        return cycles_per_day * days * self.detectors_for(joints) / self.false_alarms_per_robot

    @property
    def budget_text(self) -> str:
        """The false-alarm budget as a person reads it."""
        if self.arl0_cycles is not None:
            return f"mean run length to a false alarm {self.arl0:.3g} cycles per detector"
        return (f"{self.false_alarms_per_robot:g} false alarm(s) per robot-{self.budget_period} "
                f"({self.detectors_per_robot} detectors at {self.cycles_per_day:g} cycles a day: "
                f"{self.arl0:.3g} cycles per detector)")

    def __post_init__(self) -> None:
        if isinstance(self.joints_per_robot, float) and self.joints_per_robot.is_integer():   # TOML's optional number
            object.__setattr__(self, "joints_per_robot", int(self.joints_per_robot))
        object.__setattr__(self, "healthy_drift", healthy_drift(self.healthy_drift))
        object.__setattr__(self, "warm_up_law", warm_up_law(self.warm_up_law))
        object.__setattr__(self, "warm_up_law_friction", warm_up_law(self.warm_up_law_friction, "warm_up_law_friction",
                                                                     WARM_UP_LAW_FRICTION))
        object.__setattr__(self, "learned_sd_prior_friction", learned_sd_prior(self.learned_sd_prior_friction))
        object.__setattr__(self, "steady_drift", healthy_drift(self.steady_drift, "steady_drift", STEADY_DRIFT))
        object.__setattr__(self, "steady_drift_joint", healthy_drift(self.steady_drift_joint, "steady_drift_joint",
                                                                     STEADY_DRIFT_JOINT))
        object.__setattr__(self, "steady_wander", steady_wander(self.steady_wander))
        object.__setattr__(self, "temperature_slack", temperature_slack(self.temperature_slack))
        for name in ("calibrate_at", "steady_calibrate_at"):
            require(getattr(self, name) in CALIBRATE_AT, f"decision.{name}",
                    f"{getattr(self, name)!r}; choose one of {CALIBRATE_AT}")
        require(isinstance(self.steady_relearn, bool), "decision.steady_relearn",
                f"must be true or false, got {self.steady_relearn!r}")
        _ = self.settling                                         # validates the settling keys
        self._check_budget()
        unknown = [q for q in self.quantities if q not in QUANTITIES]
        require(not unknown, "decision.quantities", f"unknown {unknown}; registered: {sorted(QUANTITIES)}")
        require(len(set(self.quantities)) == len(self.quantities), "decision.quantities",
                f"listed twice: {list(self.quantities)}")
        hold = self.warm_up_hold
        require(isinstance(hold, tuple) and all(q in QUANTITIES for q in hold), "decision.warm_up_hold",
                f"a list of quantities of {sorted(QUANTITIES)}, got {hold!r}")
        require(isinstance(self.pause_hold_cycles, int) and not isinstance(self.pause_hold_cycles, bool)
                and 0 <= self.pause_hold_cycles <= 100, "decision.pause_hold_cycles",
                f"must be 0 … 100 cycles, got {self.pause_hold_cycles!r}")
        require(isinstance(self.pause_hold_min_h, (int, float)) and not isinstance(self.pause_hold_min_h, bool)
                and 0 <= self.pause_hold_min_h <= 1000, "decision.pause_hold_min_h",
                f"must be 0 … 1000 h, got {self.pause_hold_min_h!r}")
        margin = self.warm_up_hold_margin
        require(isinstance(margin, (int, float)) and not isinstance(margin, bool) and 0 <= margin <= 50,
                "decision.warm_up_hold_margin", f"must be 0 … 50 °C, got {margin!r}")
        for quantity in self.quantities:
            try:
                self.detector_config(quantity)
                self.detector_config(quantity, friction_temperature=True)
            except ConfigError as exc:      # "field: message" → "decision.<config key> (quantity …): message"
                field, _, message = str(exc).partition(": ")
                if QUANTITIES[quantity].dim > 1:
                    field = {"pf": "pf_joint", "density": "density_joint"}.get(field, field)
                field = {"arl0": "arl0_cycles"}.get(field, field)
                raise ConfigError(f"decision.{field} (quantity '{quantity}'): {message}") from None

    def _check_budget(self) -> None:
        require(self.budget_period in BUDGET_PERIODS, "decision.budget_period",
                f"{self.budget_period!r}; choose one of {sorted(BUDGET_PERIODS)}")
        for name in ("false_alarms_per_robot", "cycles_per_day"):
            value = getattr(self, name)
            require(isinstance(value, (int, float)) and not isinstance(value, bool) and 0 < value <= 1e6,
                    f"decision.{name}", f"must be a number > 0 and ≤ 1e6, got {value!r}")
        require(self.joints_per_robot is None or isinstance(self.joints_per_robot, int)
                and not isinstance(self.joints_per_robot, bool)
                and 1 <= self.joints_per_robot <= MAX_JOINTS_PER_ROBOT, "decision.joints_per_robot",
                f"must be 1 … {MAX_JOINTS_PER_ROBOT}, got {self.joints_per_robot!r}")
        if self.arl0_cycles is None:
            require(MIN_ARL0 <= self.arl0 <= MAX_ARL0, "decision.false_alarms_per_robot",
                    f"{self.budget_text} is outside {MIN_ARL0:g} … {MAX_ARL0:g} cycles per detector; state a "
                    f"budget a {self.budget_period} of {self.cycles_per_day:g} cycles can deliver")

    def detector_config(self, quantity: str, friction_temperature: bool = False) -> DetectorConfig:
        """``quantity``'s detector settings; ``friction_temperature``: on a joint whose detectors follow the
        lubricant temperature read from the friction (no motor temperature), calibrated for its warm-up law."""
        spec = QUANTITIES[quantity]
        vector = spec.dim > 1
        drifting = self.calibrate_at == "healthy_drift"
        steady_drifting = self.steady_calibrate_at == "healthy_drift"
        steady_drift = self.steady_drift_joint if vector else self.steady_drift
        laws = {**self.warm_up_law, **self.warm_up_law_friction} if friction_temperature else self.warm_up_law
        law = laws.get(spec.inputs[0], ()) if drifting and not vector else ()
        drift = [law[:2] if law else self.healthy_drift[q] for q in spec.inputs] if drifting else []
        spread_mean, spread_sd, skew = tuple(law[2:3]), tuple(law[3:4]), tuple(law[5:6])
        own_law = drifting and vector and friction_temperature and any(self.warm_up_law_friction.get(q)
                                                                       for q in spec.inputs)
        axis_laws = [laws.get(q, ()) if own_law else () for q in spec.inputs]   # its axes from their laws, no wander
        if any(axis_laws):
            drift = [a[:2] if a else d for a, d in zip(axis_laws, drift)]
            spread_mean, spread_sd, skew = (tuple(a[k] if a else 0.0 for a in axis_laws) for k in (2, 3, 5))
        priors = [self.learned_sd_prior_friction.get(q, (0.0, 1.0)) if friction_temperature else (0.0, 1.0)
                  for q in spec.inputs]      # the warm-up nominal's learned sd, shrunk towards the input's own
        if not any(k for k, _ in priors):
            priors = []
        return DetectorConfig(dim=spec.dim, n_nominal=self.n_nominal,
                              density=self.density_joint if vector else self.density,
                              pf=self.pf_joint if vector else self.pf, window=self.window,
                              gamma0=self.gamma0, rho=self.rho, arl0=self.arl0, direction=self.direction,
                              allowance=self.allowance, clip_sigma=self.clip_sigma,
                              calibration_draws=self.calibration_draws,
                              calibration_steps=self.calibration_steps, calibrate_at=self.calibrate_at,
                              steady_at=self.steady_calibrate_at, steady_nominal=self.steady_nominal,
                              steady_density=self.steady_density, steady_transform=self.steady_transform,
                              steady_simulate_from=self.steady_simulate_from,
                              transform_axes=tuple(self.log_scale and q in LOG_SCALE for q in spec.inputs) if vector
                              else (True,),     # a scalar: its one input (the wear score is skewed too)
                              drift_mean=tuple(d[0] for d in drift), drift_sd=tuple(d[1] for d in drift),
                              spread_mean=spread_mean, spread_sd=spread_sd,
                              warm_up_wander=tuple(law[4:5]) if law and law[4] > 0 else (),
                              warm_up_skew=skew if any(skew) else (),
                              steady_drift_mean=tuple(steady_drift[q][0] for q in spec.inputs if steady_drifting),
                              steady_drift_sd=tuple(steady_drift[q][1] for q in spec.inputs if steady_drifting),
                              steady_wander=tuple(self.steady_wander[q] for q in spec.inputs if steady_drifting),
                              sd_prior_count=tuple(k for k, _ in priors), sd_prior_sd=tuple(sd for _, sd in priors))

    def fingerprint(self) -> dict[str, Any]:
        return learned_settings({**asdict(self), "quantities": list(self.quantities)})


def learned_settings(fingerprint: dict[str, Any]) -> dict[str, Any]:
    """A decision fingerprint, current or saved, without what is not learned (:data:`SCHEDULE_KEYS`,
    :data:`CALIBRATION_KEYS`) and without the steady settings where they are the defaults (states saved
    before these settings existed still match)."""
    skipped = (*SCHEDULE_KEYS, *CALIBRATION_KEYS, *PER_DETECTOR_KEYS)
    return without_default_steady({k: v for k, v in fingerprint.items() if k not in skipped})

