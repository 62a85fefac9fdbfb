"""The shape every per-cycle feature of a joint has, and what it gets and gives (docs/ARCHITECTURE.md).

A *feature* turns one closed cycle of one joint into a record section (``"wear"``, ``"kl"``, …) and
per-cycle *quantities* (named scalars) that detectors watch. Features that need the raw samples also
bin them while the cycle runs (:meth:`Feature.update_samples`). Adding a detector = one feature module
plus one entry in :mod:`edge_monitor.features.registry`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any, Mapping, Protocol

import numpy as np
from numpy.typing import NDArray

from edge_monitor.features.friction_extraction import FrictionCurve


@dataclass(frozen=True)
class CycleInput:
    """Everything one joint's cycle gives the features once it is closed.

    ``friction``: the cycle's friction curve (speeds rad/s, torque and stderr dimensionless);
    ``load_mean``/``load_std``: the controller's load estimate over the cycle (dimensionless, None if
    no JointStatus frame arrived); ``motor_temperature``: mean motor temperature [°C] or None;
    ``t``: controller time at the end of the cycle [s]; ``partial``: the cycle's start was not seen.
    """

    joint: int
    cycle: int
    t: float
    friction: FrictionCurve
    load_mean: float | None = None
    load_std: float | None = None
    motor_temperature: float | None = None
    partial: bool = False


#: σl of a load measured at the plateaus [fraction of max torque]: the mean of (τ⁺ + τ⁻)/2 over the levels is
#: within 2·10⁻³ of the simulated truth (tests/test_kl_load_compensation.py); 0.01 with margin. The
#: controller's estimate has σl ≈ 0.1.
MEASURED_LOAD_STD = 0.01


def cycle_load(cycle: CycleInput, source: str = "measured") -> tuple[float, str] | None:
    """The cycle's |τl| and where it comes from: with ``source = "measured"`` the torque the test cycle's
    plateaus carried (``FrictionCurve.load_torque``, to the torque noise) where there is one, else (or with
    ``"estimate"``) the controller's estimate; None with neither."""
    measured, estimate = cycle.friction.load_torque, cycle.load_mean
    if source == "measured" and measured is not None and math.isfinite(measured):
        return abs(measured), "measured"
    if estimate is not None and math.isfinite(estimate):
        return abs(estimate), "estimate"
    return None


@dataclass
class FeatureOutput:
    """A feature's answer for one cycle: its record section, its quantities (NaN when missing),
    ``reason`` when it has no value, and ``extras`` for viewers (not published)."""

    section: dict[str, Any]
    values: dict[str, float]
    reason: str | None = None
    extras: dict[str, Any] = field(default_factory=dict)


class Feature(Protocol):
    """A per-cycle feature of one joint (see the module docstring)."""

    @property
    def name(self) -> str:
        """The record section it fills."""

    @property
    def quantities(self) -> tuple[str, ...]:
        """The per-cycle quantities it produces."""

    def update_samples(self, torque: NDArray[np.float64], speed: NDArray[np.float64],
                       segment: NDArray[np.int64] | None) -> None:
        """Take one block of the open cycle's samples (torque dimensionless, speed rad/s)."""

    def update(self, cycle: CycleInput, context: Mapping[str, float]) -> FeatureOutput:
        """Close the cycle: the section, the quantities, learning steps. ``context``: the quantities
        the features registered before this one produced for this cycle (e.g. ``temperature``)."""

    def pause(self, seconds: float) -> None:
        """The joint stood still (sent no samples) for ``seconds`` before the next block."""

    def discard_cycle(self) -> None:
        """Drop the open cycle's samples (duplicate or partial cycle)."""

    def reset(self) -> None:
        """Declared maintenance: forget what was learned."""

    def state_dict(self) -> dict[str, Any]:
        """JSON-ready learned state, including the config it was learned with."""
