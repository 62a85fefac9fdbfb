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


@dataclass(frozen=True)
class FeatureSpec:
    """How to build, restore and describe one feature.

    ``enabled(settings)``: whether the feature runs; ``build(joint, settings)``: a fresh feature;
    ``restore(joint, settings, state)``: from a saved state (raises StateMismatch on a config change);
    ``empty_section``: its record section when it does not run.
    """

    name: str
    quantities: tuple[str, ...]
    empty_section: dict[str, Any]
    enabled: Callable[[FeatureSettings], bool]
    build: Callable[[int, FeatureSettings], Feature]
    restore: Callable[[int, FeatureSettings, dict[str, Any]], Feature]


@dataclass(frozen=True)
class QuantitySpec:
    """A quantity a detector can watch: made of one or more feature quantities (``inputs``).

    ``log_scale``: the feature's value is watched as its logarithm when ``decision.log_kl`` is on
    (positive, right-skewed quantities such as KL distances).
    """

    name: str
    inputs: tuple[str, ...]
    log_scale: bool = False

    @property
    def dim(self) -> int:
        return len(self.inputs)


FEATURES: tuple[FeatureSpec, ...] = (
    FeatureSpec("wear", WearFeature.quantities, WEAR_EMPTY,
                enabled=lambda s: s.wear.enabled,
                build=lambda joint, s: WearFeature(s.wear, s.friction_for(joint)),
                restore=lambda joint, s, state: WearFeature.from_state(s.wear, s.friction_for(joint), state)),
    FeatureSpec("kl", KLMonitor.quantities, KL_EMPTY,
                enabled=lambda s: s.kl.enabled,
                build=lambda joint, s: KLMonitor(s.kl),
                restore=lambda joint, s, state: KLMonitor.from_state(s.kl, state)),
)

QUANTITIES: dict[str, QuantitySpec] = {q.name: q for q in (
    QuantitySpec("wear", ("wear",)),
    QuantitySpec("kl_raw", ("kl_raw",), log_scale=True),
    QuantitySpec("kl_weighted", ("kl_weighted",), log_scale=True),
    QuantitySpec("joint", ("wear", "kl_raw", "kl_weighted")),
)}


def feature_of(quantity: str) -> str:
    """Name of the feature that produces a scalar feature quantity."""
    for spec in FEATURES:
        if quantity in spec.quantities:
            return spec.name
    raise KeyError(quantity)
