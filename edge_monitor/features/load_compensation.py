"""Torque samples moved to a reference load with the joint's friction model (docs/KL_DETECTOR.md,
"Load compensation").

The load torque the gearbox carries raises friction by ``s(|v|)·|τl|`` with the load sensitivity
``s(v) = fcl + fsl·exp(−(v/vsl)^α)`` of the §1 model (docs/ALGORITHMS.md §1): most below ≈ 25 rad/s.
A cycle at another load than the nominal cycles therefore has another torque density, although
nothing wore. Each sample is moved to the reference load:

    τ ← τ − ε·c(v),   c(v) = sign(v)·s(|v|),   ε = |τl| − |τl,ref|

The cycle's load is known only at its end: measured at the plateaus as the mean of ``(τ⁺ + τ⁻)/2``
(the torque carried at the test angle, friction cancels; ``FrictionCurve.load_torque``), else the
controller's estimate. So the coefficient ``c`` of every sample goes into the capture as it is binned
(:class:`~edge_monitor.stats.sliced_kde.SlicedKDE`) and ε is applied when the cycle closes. The
reference is the first usable cycle's load; a declared maintenance relearns it with the nominal.
Units: torque and load dimensionless (fraction of the joint's maximum torque), speed rad/s.
"""

from __future__ import annotations

import math
from typing import Any, Callable

import numpy as np
from numpy.typing import NDArray

from edge_monitor.features.base import CycleInput, cycle_load
from joint_model import FrictionParams
from joint_model.friction import load_sensitivity

#: Where the cycle's load comes from: the plateaus (falling back to the controller's estimate), the
#: controller's estimate, or nowhere (no compensation).
SOURCES = ("measured", "estimate", "off")


class LoadCompensation:
    """See the module docstring. ``source``: "measured" or "estimate"."""

    def __init__(self, params: FrictionParams, source: str = "measured") -> None:
        self.params = params
        self.source = source
        self.reference: float | None = None

    def coefficients(self, speed: NDArray[np.float64]) -> NDArray[np.float64]:
        """``c = sign(v)·s(|v|) = ∂τ/∂|τl|`` of every sample [torque per unit load]."""
        return np.sign(speed) * load_sensitivity(speed, self.params)

    def bound(self, min_speed: float, weights: Callable[[NDArray[np.float64]], NDArray[np.float64]] | None = None
              ) -> float:
        """Largest |coefficient| of a sample at least ``min_speed`` fast: s(min_speed); with ``weights``
        (the weighted channel, whose coefficients are centred causally: w·(c − C_t)) 2·max w·s(min_speed)."""
        bound = float(load_sensitivity(min_speed, self.params)) * 1.001
        if weights is None:
            return bound
        speeds = np.geomspace(max(min_speed, 1e-3), 1e3, 4000)
        return 2.0 * bound * float(weights(speeds).max())

    def cycle_load(self, cycle: CycleInput) -> tuple[float, str] | None:
        """The cycle's |τl| and where it comes from, or None if it has neither a measured nor an
        estimated load."""
        return cycle_load(cycle, self.source)

    def change(self, load: tuple[float, str] | None) -> tuple[float | None, dict[str, Any] | None]:
        """ε = |τl| − reference of a usable cycle (the first one sets the reference) and its record
        ``{"value", "reference", "source"}``; (None, None) when the load is unknown."""
        if load is None:
            return None, None
        value, source = load
        if self.reference is None:
            self.reference = value
        return value - self.reference, {"value": value, "reference": self.reference, "source": source}

    def reset(self) -> None:
        """Relearn the reference (declared maintenance: the nominal density is relearned too)."""
        self.reference = None

    def state_dict(self) -> dict[str, Any]:
        return {"reference": self.reference}

    def load_state(self, state: Any) -> None:
        value = state.get("reference") if isinstance(state, dict) else None
        self.reference = float(value) if isinstance(value, (int, float)) and math.isfinite(value) else None
