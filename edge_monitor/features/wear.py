"""The wear feature: one maximum-likelihood wear estimate per cycle (docs/ALGORITHMS.md §3).

Wraps :class:`~edge_monitor.features.wear_estimation.WearEstimator` for the agent: takes the cycle's
friction curve and its load — the torque the test cycle's plateaus carried where they measured it, else
the controller's load estimate, else the configured prior — and gives the ``"wear"`` record section and
the quantity ``wear``.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass
from typing import Any, Mapping

import numpy as np
from numpy.typing import NDArray

from edge_monitor.errors import check_learned_with, require
from edge_monitor.features.base import MEASURED_LOAD_STD, CycleInput, FeatureOutput, cycle_load
from edge_monitor.features.temperature_prior import MotorTemperaturePrior
from edge_monitor.features.wear_estimation import ESTIMATION_METHODS, WearEstimator
from joint_model import CRITICAL_WEAR, FRICTION_NOISE_STD, FrictionParams

#: Where the load the likelihood takes comes from (``[wear] load``).
LOAD_SOURCES = ("measured", "estimate")
#: Section of a symptom when there is no estimate.
EMPTY_SECTION: dict[str, Any] = {"estimate": None, "std": None, "temperature": None}


@dataclass(frozen=True)
class WearConfig:
    """Wear estimation settings (the ``[wear]`` table), validated once, here.

    ``method``: "marginal" (ξ ~ U(temperature range) marginalised for every N) or "joint" (constrained
    NLS in [ξ, ϖ] for N ≥ 2); see docs/WEAR_ESTIMATION.md. Temperatures in °C, loads dimensionless.
    """

    enabled: bool = True
    method: str = "marginal"
    noise_std: float = FRICTION_NOISE_STD    # σ of a friction datum
    temperature_min: float = 30.0            # plausible lubricant temperature range of the site [°C]
    temperature_max: float = 80.0
    motor_temperature_prior: bool = True     # prior on ξ from the controller's motor temperature
    prior_cycles: int = 20                   # cycles that learn how the motor temperature relates to ξ
    default_load_mean: float = 0.5           # μl when the controller sends no load estimate
    default_load_std: float = 0.1            # σl when the controller sends none
    load: str = "measured"                   # "measured" at the plateaus where they are, else the estimate; "estimate"
    critical: float = CRITICAL_WEAR

    def __post_init__(self) -> None:
        require(self.method in ESTIMATION_METHODS, "wear.method",
                f"must be one of {ESTIMATION_METHODS}, got {self.method!r}")
        require(math.isfinite(self.noise_std) and 0 < self.noise_std <= 1, "wear.noise_std",
                f"must be in (0, 1], got {self.noise_std}")
        require(-40 <= self.temperature_min < self.temperature_max <= 150, "wear.temperature_min",
                f"need -40 <= temperature_min < temperature_max <= 150 °C, got {self.temperature_min} … "
                f"{self.temperature_max}")
        require(math.isfinite(self.default_load_mean) and abs(self.default_load_mean) <= 1, "wear.default_load_mean",
                f"must be within ±1, got {self.default_load_mean}")
        require(math.isfinite(self.default_load_std) and 0 <= self.default_load_std <= 1, "wear.default_load_std",
                f"must be 0 … 1, got {self.default_load_std}")
        require(self.load in LOAD_SOURCES, "wear.load", f"must be one of {LOAD_SOURCES}, got {self.load!r}")
        require(math.isfinite(self.critical) and 0 < self.critical <= 100, "wear.critical",
                f"must be in (0, 100], got {self.critical}")
        require(isinstance(self.prior_cycles, int) and 3 <= self.prior_cycles <= 10_000, "wear.prior_cycles",
                f"must be 3 … 10000 cycles, got {self.prior_cycles!r}")

    def fingerprint(self) -> dict[str, Any]:
        """The settings the estimates depend on (``enabled`` and ``critical`` do not change them)."""
        out = asdict(self)
        del out["enabled"], out["critical"]
        return out


class WearFeature:
    """Per-cycle wear estimate of one joint. With ``motor_temperature_prior`` it first learns how the
    controller's motor temperature relates to the lubricant temperature the friction data show
    (:mod:`edge_monitor.features.temperature_prior`) and then uses it as a prior on ξ. Publishes the
    quantities ``wear`` (the posterior mean of ϖ, continuous near ϖ = 0 where the maximum-likelihood
    estimate piles up at 0), ``wear_evidence`` (posterior mean / std), ``wear_score`` (the signed
    root of the likelihood ratio against no wear, ≈ N(0, 1) on a healthy joint at any temperature:
    what the detector watches) and ``temperature`` (ξ̂, °C)."""

    name = "wear"
    quantities = ("wear", "wear_evidence", "wear_score", "temperature")

    def __init__(self, config: WearConfig, params: FrictionParams,
                 relation: tuple[float, float] | None = None, joint: int | None = None) -> None:
        self.config = config
        self.params = params
        self.estimator = WearEstimator(params=params, noise_std=config.noise_std,
                                       temperature_range=(config.temperature_min, config.temperature_max),
                                       method=config.method)
        self.prior = MotorTemperaturePrior(config.prior_cycles, None if joint is None
                                           else f"joint {joint}: motor-temperature relation")
        if relation is not None:     # learned with the joint's model (features/joint_model_learning.py)
            self.prior.set_relation(*relation)

    def update_samples(self, torque: NDArray[np.float64], speed: NDArray[np.float64],
                       segment: NDArray[np.int64] | None) -> None:
        """The wear estimate needs only the friction curve."""

    def load(self, cycle: CycleInput) -> tuple[float, float]:
        """The cycle's load μl and its std σl: with ``load = "measured"`` the torque the test cycle's plateaus
        carried (:func:`~edge_monitor.features.base.cycle_load`, σl :data:`MEASURED_LOAD_STD`), else the
        controller's estimate as it came, else the configured prior. An error of the estimate moves every
        friction datum of the cycle alike by s(v)·(μl − |τl|), which the likelihood can only read as
        temperature or wear."""
        c = self.config
        found = cycle_load(cycle, c.load)
        if found is not None and found[1] == "measured":
            return found[0], MEASURED_LOAD_STD
        return (c.default_load_mean if cycle.load_mean is None else cycle.load_mean,
                c.default_load_std if cycle.load_std is None else cycle.load_std)

    def update(self, cycle: CycleInput, context: Mapping[str, float]) -> FeatureOutput:
        c = self.config
        load_mean, load_std = self.load(cycle)
        curve = cycle.friction
        use_prior = c.motor_temperature_prior
        if use_prior:
            self.prior.observe_motor(cycle.motor_temperature)
        prior = self.prior.prior() if use_prior else None
        estimate = self.estimator.estimate(np.asarray(curve.speeds), np.asarray(curve.torque), load_mean, load_std,
                                           friction_stderr=np.asarray(curve.stderr) if curve.stderr else None,
                                           temperature_prior=prior)
        if use_prior and not self.prior.learned:
            self.prior.learn(estimate.temperature)
        values = {"wear": estimate.posterior_mean, "wear_evidence": estimate.evidence, "wear_score": estimate.score,
                  "temperature": math.nan if estimate.temperature is None else estimate.temperature}
        section = {**estimate.to_record(), "temperature_prior": _prior_record(prior)}
        return FeatureOutput(section=section, values=values, reason=estimate.reason)

    def pause(self, seconds: float) -> None:
        """Nothing to do: the temperature prior follows the motor temperature, which cools by itself."""

    def discard_cycle(self) -> None:
        """Nothing is accumulated during the cycle."""

    def reset(self) -> None:
        """Declared maintenance: relearn the motor-temperature relation."""
        self.prior.reset()

    def state_dict(self) -> dict[str, Any]:
        return {"config": self.fingerprint(), "prior": self.prior.state_dict()}

    def fingerprint(self) -> dict[str, Any]:
        """What the estimates depend on: the config and the friction parameters."""
        return {**self.config.fingerprint(), "friction": self.params.to_dict()}

    @classmethod
    def from_state(cls, config: WearConfig, params: FrictionParams, state: dict[str, Any],
                   relation: tuple[float, float] | None = None, joint: int | None = None) -> "WearFeature":
        feature = cls(config, params, relation, joint)
        check_learned_with("wear", state, feature.fingerprint())
        if isinstance(state.get("prior"), dict):
            feature.prior.load_state(state["prior"])
        return feature


def _prior_record(prior: tuple[float, float] | None) -> dict[str, float] | None:
    """The ``wear.temperature_prior`` field: the motor-temperature prior on ξ this cycle's estimate
    used, ``{"mean", "std"}`` [°C], or ``None`` (flat over the site range: relation still being
    learned, no motor temperature this cycle, or the prior switched off)."""
    if prior is None:
        return None
    return {"mean": round(prior[0], 3), "std": round(prior[1], 3)}
