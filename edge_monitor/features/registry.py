"""Registered per-cycle features and the quantities detectors can watch.

A feature (see :mod:`edge_monitor.features.base`) is registered with a builder and a restorer; every
quantity it produces is listed in :data:`QUANTITIES`, as well as vector quantities made of several. A
new detector is one feature module plus one :class:`FeatureSpec` here; the joint monitor, the records
and the sinks handle it generically.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Callable, Protocol

from edge_monitor.features.base import Feature
from edge_monitor.features.kl_monitor import EMPTY_SECTION as KL_EMPTY
from edge_monitor.features.kl_monitor import KLConfig, KLMonitor
from edge_monitor.features.wear import EMPTY_SECTION as WEAR_EMPTY
from edge_monitor.features.wear import WearConfig, WearFeature
from joint_model import FrictionParams


class FeatureSettings(Protocol):
    """What feature builders read from the agent configuration."""

    @property
    def wear(self) -> WearConfig: ...

    @property
    def kl(self) -> KLConfig: ...

    def friction_for(self, joint: int) -> FrictionParams: ...

    def temperature_relation(self, joint: int) -> tuple[float, float] | None: ...

    def model_pending(self) -> bool:
        """Whether the joint's model is still being learned (features built now are rebuilt with it)."""
        ...


@dataclass(frozen=True)
class FeatureSpec:
    """How to build, restore and describe one feature.

    ``enabled(settings)``: whether the feature runs; ``build(joint, settings)``: a fresh feature;
    ``restore(joint, settings, state)``: from a saved state (raises StateMismatch on a config change);
    ``empty_section``: its record section when it does not run; ``waits_for_model``: it starts only
    once the joint's own friction model is learned (its nominal learning would otherwise be wasted).
    """

    name: str
    quantities: tuple[str, ...]
    empty_section: dict[str, Any]
    enabled: Callable[[FeatureSettings], bool]
    build: Callable[[int, FeatureSettings], Feature]
    restore: Callable[[int, FeatureSettings, dict[str, Any]], Feature]
    waits_for_model: bool = False


#: Feature quantities watched as their logarithm when ``decision.log_scale`` is on: positive and
#: right-skewed (the KL distances); their logarithms are close to normal, and the
#: nominal densities of 60 values have thin tails.
LOG_SCALE = frozenset({"kl_raw", "kl_weighted"})


@dataclass(frozen=True)
class QuantitySpec:
    """A quantity a detector can watch: made of one or more feature quantities (``inputs``)."""

    name: str
    inputs: tuple[str, ...]

    @property
    def dim(self) -> int:
        return len(self.inputs)

    @property
    def log_scale(self) -> bool:
        """Whether any input is watched as its logarithm (see :data:`LOG_SCALE`)."""
        return any(q in LOG_SCALE for q in self.inputs)


FEATURES: tuple[FeatureSpec, ...] = (
    FeatureSpec("wear", WearFeature.quantities, WEAR_EMPTY,
                enabled=lambda s: s.wear.enabled,
                build=lambda joint, s: WearFeature(s.wear, s.friction_for(joint), s.temperature_relation(joint),
                                                   _reporting(joint, s)),
                restore=lambda joint, s, state: WearFeature.from_state(s.wear, s.friction_for(joint), state,
                                                                       s.temperature_relation(joint),
                                                                       _reporting(joint, s))),
    FeatureSpec("kl", KLMonitor.quantities, KL_EMPTY,
                enabled=lambda s: s.kl.enabled,
                build=lambda joint, s: KLMonitor(s.kl, s.friction_for(joint)),
                restore=lambda joint, s, state: KLMonitor.from_state(s.kl, state, s.friction_for(joint)),
                waits_for_model=True),
)

QUANTITIES: dict[str, QuantitySpec] = {q.name: q for q in (
    QuantitySpec("wear", ("wear_score",)),
    QuantitySpec("kl_raw", ("kl_raw",)),
    QuantitySpec("kl_weighted", ("kl_weighted",)),
    QuantitySpec("joint", ("wear_score", "kl_raw", "kl_weighted")),
)}


def feature_of(quantity: str) -> str:
    """Name of the feature that produces a scalar feature quantity."""
    for spec in FEATURES:
        if quantity in spec.quantities:
            return spec.name
    raise KeyError(quantity)


def _reporting(joint: int, settings: FeatureSettings) -> int | None:
    """The joint a wear feature names when its own motor-temperature relation looks implausible; None
    (quiet) while the joint's model is learning: the model learns the relation, says so itself, and the
    feature is rebuilt with it."""
    return None if settings.model_pending() else joint
