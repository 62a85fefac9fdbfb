"""On-the-fly friction extraction: ``τf(v) = (τ⁺ − τ⁻)/2`` per speed level and cycle (docs/ALGORITHMS.md §2).

At constant speed the inertial torque vanishes and gravity is the same in both directions, so half
the difference of the mean torques of the forward and backward plateaus is the friction at that
speed. Memory is O(speed levels): per level and direction only the pooled moments of the steady
plateau samples are kept.

The standard error of a plateau mean accounts for serial correlation of the torque samples with
the AR(1) variance inflation ``(1 + r1)/(1 − r1)`` (r1 = lag-1 autocorrelation, clipped to
[0, 0.95]), because controller torque noise is not white.

Units: speed rad/s, torque dimensionless.
"""

from __future__ import annotations

import math
from collections import Counter
from dataclasses import dataclass, field

import numpy as np

from edge_monitor.features.segmentation import PlateauStat
from protocol.frames import MAX_SPEED_LEVELS, TORQUE_SCALE

#: |torque| at or beyond this is treated as saturated: 32000 of the 32768 LSB of the wire range (±1.6384).
TORQUE_SATURATION = TORQUE_SCALE * 32000


@dataclass
class DirectionMoments:
    """Pooled moments of the steady torque samples of one direction of one level."""

    n: int = 0
    mean: float = 0.0
    m2: float = 0.0
    var_of_mean: float = 0.0   # Σ over plateaus, combined as independent means weighted by n
    speed_sum: float = 0.0

    def add(self, p: PlateauStat) -> None:
        n = self.n + p.n
        delta = p.mean - self.mean
        self.mean += delta * p.n / n
        self.m2 += p.m2 + delta * delta * self.n * p.n / n
        r1 = min(max(p.lag1, 0.0), 0.95)
        plateau_var_mean = (p.variance if p.n > 1 else 0.0) / p.n * (1 + r1) / (1 - r1)
        # Pooled mean = Σ (n_i/n) m_i → Var = Σ (n_i/n)² Var(m_i); rescale the running sum.
        self.var_of_mean = (self.var_of_mean * self.n ** 2 + plateau_var_mean * p.n ** 2) / n ** 2
        self.speed_sum += p.speed_mean * p.n
        self.n = n


@dataclass
class FrictionCurve:
    """Friction data of one cycle: one datum per speed level measured in both directions."""

    speeds: list[float]
    torque: list[float]
    stderr: list[float]
    skipped: dict[str, int] = field(default_factory=dict)
    #: the joint torque the gearbox carried at the test angle: mean over the data of ``(τ⁺ + τ⁻)/2``
    #: (gravity and payload; friction cancels), None without data. The load of the §1 model is its
    #: magnitude (docs/KL_DETECTOR.md, "Load compensation"; the wear likelihood's, docs/WEAR_ESTIMATION.md).
    load_torque: float | None = None

    def to_record(self) -> dict:
        return {"speeds": self.speeds, "torque": self.torque, "stderr": self.stderr}

    @property
    def n_points(self) -> int:
        return len(self.speeds)


@dataclass
class FrictionExtractor:
    """Per-joint accumulator: ``update(plateau)`` during the cycle, ``end_cycle()`` returns the curve."""

    speeds: tuple[float, ...]
    min_samples: int = 50
    _moments: dict[tuple[int, int], DirectionMoments] = field(default_factory=dict)
    _skipped: Counter = field(default_factory=Counter)
    totals: Counter = field(default_factory=Counter)

    def update(self, plateau: PlateauStat) -> None:
        if not (math.isfinite(plateau.mean) and math.isfinite(plateau.m2)):
            self._skip("non-finite torque")
            return
        if abs(plateau.mean) >= TORQUE_SATURATION:
            self._skip("saturated torque")
            return
        if not 0 <= plateau.level < (len(self.speeds) or MAX_SPEED_LEVELS):
            self._skip("speed not in configured set")
            return
        self._moments.setdefault((plateau.level, plateau.direction), DirectionMoments()).add(plateau)

    @property
    def n_pending(self) -> int:
        """Number of (level, direction) entries collected in the open cycle."""
        return len(self._moments)

    def has(self, level: int, direction: int) -> bool:
        """Whether this cycle already holds data of ``level`` in ``direction``."""
        return (level, direction) in self._moments

    def skip(self, reason: str, count: int = 1) -> None:
        """Record a datum skipped upstream (e.g. a plateau cut short) for this cycle."""
        self._skip(reason, count)

    def _skip(self, reason: str, count: int = 1) -> None:
        self._skipped[reason] += count
        self.totals[reason] += count

    def end_cycle(self) -> FrictionCurve:
        speeds: list[float] = []
        torque: list[float] = []
        stderr: list[float] = []
        carried: list[float] = []
        for level in sorted({lvl for lvl, _ in self._moments}):
            fwd, bwd = self._moments.get((level, 1)), self._moments.get((level, -1))
            if fwd is None or bwd is None:
                self._skip("missing reverse direction")
                continue
            if min(fwd.n, bwd.n) < self.min_samples:
                self._skip("too few steady samples")
                continue
            speeds.append(float(self.speeds[level]) if self.speeds else _measured_speed(fwd, bwd))
            torque.append(0.5 * (fwd.mean - bwd.mean))
            carried.append(0.5 * (fwd.mean + bwd.mean))
            stderr.append(0.5 * math.sqrt(fwd.var_of_mean + bwd.var_of_mean))
        order = np.argsort(speeds)
        curve = FrictionCurve(speeds=[speeds[i] for i in order], torque=[torque[i] for i in order],
                              stderr=[stderr[i] for i in order], skipped=dict(self._skipped),
                              load_torque=_carried(carried))
        self._moments.clear()
        self._skipped.clear()
        return curve

    def state_dict(self) -> dict:
        return {"speeds": list(self.speeds), "min_samples": self.min_samples, "totals": dict(self.totals)}

    @classmethod
    def from_state(cls, state: dict) -> "FrictionExtractor":
        return cls(speeds=tuple(state["speeds"]), min_samples=int(state["min_samples"]),
                   totals=Counter(state.get("totals", {})))


def _measured_speed(fwd: DirectionMoments, bwd: DirectionMoments) -> float:
    """The datum's speed when levels are not configured: the mean |speed| of both directions [rad/s],
    to 1e-3 rad/s (the mean of hundreds of samples of 0.005 rad/s resolution)."""
    return round(0.5 * (abs(fwd.speed_sum) / fwd.n + abs(bwd.speed_sum) / bwd.n), 3)


#: Decimals the carried torque is kept to: it is measured to ≈ 10⁻³ (the torque noise over a plateau); the digits
#: below 10⁻⁹ are the summation order's (how the samples came in blocks), and the wear likelihood, flat near
#: ϖ = 0, would carry them into its optimiser's answer (tests/test_agent_pipeline.py, the block test).
_CARRIED_DECIMALS = 9


def _carried(carried: list[float]) -> float | None:
    """The mean of the levels' (τ⁺ + τ⁻)/2, rounded to :data:`_CARRIED_DECIMALS`; None without a level."""
    return round(float(np.mean(carried)), _CARRIED_DECIMALS) if carried else None
