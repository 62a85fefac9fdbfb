"""The wear feature: one maximum-likelihood wear estimate per cycle (docs/ALGORITHMS.md §3).

Wraps :class:`~edge_monitor.features.wear_estimation.WearEstimator` for the agent: takes the cycle's
friction curve and the controller's load estimate (or the configured prior when the controller sends
none) and gives the ``"wear"`` record section and the quantity ``wear``.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from edge_monitor.errors import check_learned_with, require
from edge_monitor.features.base import CycleInput, FeatureOutput
from edge_monitor.features.wear_estimation import ESTIMATION_METHODS, WearEstimator
from joint_model import CRITICAL_WEAR, FRICTION_NOISE_STD, FrictionParams

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
    temperature_max: float = 50.0
    default_load_mean: float = 0.5           # μl when the controller sends no load estimate
    default_load_std: float = 0.1            # σl when the controller sends none
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
        require(math.isfinite(self.critical) and 0 < self.critical <= 100, "wear.critical",
                f"must be in (0, 100], got {self.critical}")

    def fingerprint(self) -> dict[str, Any]:
        """The settings the estimates depend on (``enabled`` and ``critical`` do not change them)."""
        out = asdict(self)
        del out["enabled"], out["critical"]
        return out


class WearFeature:
    """Per-cycle wear estimate of one joint (stateless between cycles: nothing is learned)."""

    name = "wear"
    quantities = ("wear",)

    def __init__(self, config: WearConfig, params: FrictionParams) -> None:
        self.config = config
        self.params = params
        self.estimator = WearEstimator(params=params, noise_std=config.noise_std,
                                       temperature_range=(config.temperature_min, config.temperature_max),
                                       method=config.method)

    def update_samples(self, torque: NDArray[np.float64], speed: NDArray[np.float64],
                       segment: NDArray[np.int64] | None) -> None:
        """The wear estimate needs only the friction curve."""

    def update(self, cycle: CycleInput) -> FeatureOutput:
        c = self.config
        load_mean = c.default_load_mean if cycle.load_mean is None else cycle.load_mean
        load_std = c.default_load_std if cycle.load_std is None else cycle.load_std
        curve = cycle.friction
        estimate = self.estimator.estimate(np.asarray(curve.speeds), np.asarray(curve.torque), load_mean, load_std,
                                           friction_stderr=np.asarray(curve.stderr) if curve.stderr else None)
        return FeatureOutput(section=estimate.to_record(), values={"wear": estimate.estimate},
                             reason=estimate.reason)

    def discard_cycle(self) -> None:
        """Nothing is accumulated during the cycle."""

    def reset(self) -> None:
        """Nothing is learned."""

    def state_dict(self) -> dict[str, Any]:
        return {"config": self.fingerprint()}

    def fingerprint(self) -> dict[str, Any]:
        """What the estimates depend on: the config and the friction parameters."""
        return {**self.config.fingerprint(), "friction": self.params.to_dict()}

    @classmethod
    def from_state(cls, config: WearConfig, params: FrictionParams, state: dict[str, Any]) -> "WearFeature":
        feature = cls(config, params)
        check_learned_with("wear", state, feature.fingerprint())
        return feature
