"""Settings of the distribution-domain monitor (the ``[kl]`` table), validated once, here
(:mod:`edge_monitor.features.kl_monitor`, docs/KL_DETECTOR.md)."""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass
from typing import Any, Literal

from edge_monitor.errors import require
from edge_monitor.features.disturbance_weights import DEFAULT_ALPHA, DEFAULT_BETA, WeightFunction
from edge_monitor.features.load_compensation import SOURCES
from edge_monitor.stats.kde_stream import MAX_GRID

Window = Literal["cycle", "test", "production"]
#: ``kl.window`` values: every sample, the test cycle's segments only (codes other than 200), production only.
WINDOWS = ("cycle", "test", "production")
#: ``kl.load_compensation`` values (docs/KL_DETECTOR.md, "Load compensation").
LOAD_COMPENSATION = SOURCES


@dataclass(frozen=True)
class KLConfig:
    """Distribution-domain detector settings (the ``[kl]`` table), validated once, here.

    ``window``: "test" (the test cycle's segments: the constant-speed moves and their ramps), "cycle"
    (every sample) or "production" (segment 200 only); ``center``: compare densities of torque − cycle
    mean; ``load_compensation``: move every sample to the reference load with the joint's friction
    model, using the load torque measured at the plateaus ("measured", falling back to the
    controller's estimate), the controller's estimate ("estimate") or not at all ("off");
    ``alpha``, ``beta`` [s/rad]: weights w(v) = sech(β·v)·tanh(α·v); ``min_samples``: fewest samples a
    cycle needs for a KL value; ``cooling_time_constant_h``: the lubricant's thermal time constant, with which
    the temperature compensation predicts how far a joint cooled while it stood (a pause in its samples).
    """

    enabled: bool = True
    n_nominal_cycles: int = 10
    n_grid: int = 512
    window: str = "test"
    center: bool = True
    load_compensation: str = "measured"
    temperature_compensation: bool = True   # move samples to the reference temperature (needs the wear feature)
    min_speed: float = 10.0                 # [rad/s] slower samples are left out (module docstring)
    alpha: float = DEFAULT_ALPHA
    beta: float = DEFAULT_BETA
    min_samples: int = 1000
    cooling_time_constant_h: float = 3.04   # [h] how fast the lubricant cools while the joint stands (pauses)

    def __post_init__(self) -> None:
        require(2 <= self.n_nominal_cycles <= 1000, "kl.n_nominal_cycles",
                f"need 2 … 1000 cycles (2 for σ0), got {self.n_nominal_cycles}")
        require(64 <= self.n_grid <= MAX_GRID, "kl.n_grid", f"need 64 … {MAX_GRID} grid points, got {self.n_grid}")
        require(self.window in WINDOWS, "kl.window", f"must be one of {WINDOWS}, got {self.window!r}")
        require(self.load_compensation in LOAD_COMPENSATION, "kl.load_compensation",
                f"must be one of {LOAD_COMPENSATION}, got {self.load_compensation!r}")
        for name in ("alpha", "beta"):
            value = getattr(self, name)
            require(math.isfinite(value) and 0 <= value <= 10, f"kl.{name}", f"must be 0 … 10 s/rad, got {value}")
        require(2 <= self.min_samples <= 10_000_000, "kl.min_samples", f"need 2 … 1e7, got {self.min_samples}")
        require(math.isfinite(self.min_speed) and 0 <= self.min_speed <= 100, "kl.min_speed",
                f"must be 0 … 100 rad/s, got {self.min_speed}")
        require(isinstance(self.cooling_time_constant_h, (int, float)) and not isinstance(self.cooling_time_constant_h,
                bool) and math.isfinite(self.cooling_time_constant_h) and 0.05 <= self.cooling_time_constant_h <= 100,
                "kl.cooling_time_constant_h", f"must be 0.05 … 100 h, got {self.cooling_time_constant_h!r}")

    def fingerprint(self) -> dict[str, Any]:
        """The settings the learned grid and nominal densities depend on (not the cooling time constant:
        it only predicts the temperature after a pause)."""
        out = asdict(self)
        del out["enabled"], out["cooling_time_constant_h"]
        return out

    @property
    def weights(self) -> WeightFunction:
        return WeightFunction(alpha=self.alpha, beta=self.beta)
