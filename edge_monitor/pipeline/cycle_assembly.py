"""Assembling one joint's cycle from its sample stream: plateaus → friction curve, plus the controller's
load estimate and motor temperature over the cycle (docs/ALGORITHMS.md §2).

:class:`CycleAssembler` is the sample-level half of a joint monitor: ``update(block)`` during the cycle,
``end_cycle(...)`` gives the :class:`~edge_monitor.features.base.CycleInput` the per-cycle features
take. Memory O(speed levels). Nothing is learned: a restart begins a new (partial) cycle.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from edge_monitor.features.base import CycleInput
from edge_monitor.features.friction_extraction import FrictionExtractor
from edge_monitor.features.segmentation import PlateauConfig, PlateauDetector


@dataclass
class _Mean:
    """Running mean of the finite values received during a cycle, and the last finite spread."""

    n: int = 0
    total: float = 0.0
    spread: float = math.nan

    def add(self, values: NDArray[np.float64], spreads: NDArray[np.float64] | None = None) -> None:
        """Frames in stream order: their finite values enter the mean, the last finite spread is kept."""
        finite = values[np.isfinite(values)]
        if finite.size:
            self.n += int(finite.size)
            self.total += float(finite.sum())
        if spreads is not None:
            good = spreads[np.isfinite(spreads)]
            if good.size:
                self.spread = float(good[-1])

    def mean(self) -> float | None:
        return self.total / self.n if self.n else None

    def last_spread(self) -> float | None:
        return self.spread if math.isfinite(self.spread) else None


class CycleAssembler:
    """Friction data, load and temperature of one joint's open cycle (see the module docstring)."""

    def __init__(self, joint: int, config: PlateauConfig, rate_hz: float) -> None:
        self.joint = joint
        self.rate_hz = rate_hz
        self.plateaus = PlateauDetector(config, rate_hz)
        self.extractor = FrictionExtractor(config.speeds)    # empty: datum speeds measured
        self._load = _Mean()
        self._temperature = _Mean()
        self._cut_short_seen = 0
        self.last_tick = 0
        self.closed = 0                 # cycles closed by this joint (inferred cycles are numbered by it)

    def update(self, tick: NDArray[np.int64], speed: NDArray[np.float64], torque: NDArray[np.float64],
               segment: NDArray[np.int64] | None) -> list[CycleInput]:
        """One block of samples in tick order. With ``segment`` (the controller's segment codes) the
        production motion is kept out of the plateaus and nothing is returned: the caller closes cycles
        on the controller's status frames. Without it cycles are inferred: a plateau of a (level,
        direction) already measured in the open cycle starts a new one, and the closed cycles are
        returned (numbered by this joint's count of closed cycles)."""
        closed: list[CycleInput] = []
        for plateau in self.plateaus.update(tick, speed, torque, segment):
            if segment is None and self.extractor.has(plateau.level, plateau.direction):
                closed.append(self.end_cycle(self.closed))
            self.extractor.update(plateau)
        if tick.size:
            self.last_tick = int(tick[-1])
        return closed

    def add_status(self, load_estimate: NDArray[np.float64], load_std: NDArray[np.float64],
                   motor_temperature: NDArray[np.float64]) -> None:
        """JointStatus frames: the controller's load estimate μl, σl and the motor temperature [°C]."""
        self._load.add(np.asarray(load_estimate, dtype=float), np.asarray(load_std, dtype=float))
        self._temperature.add(np.asarray(motor_temperature, dtype=float))

    def has_data(self) -> bool:
        """Whether the open cycle holds any friction data."""
        return self.extractor.n_pending > 0

    def flush(self) -> None:
        """End of stream: close a plateau still in progress."""
        for plateau in self.plateaus.flush():
            self.extractor.update(plateau)

    def end_cycle(self, cycle: int, partial: bool = False) -> CycleInput:
        """Close the open cycle; the next samples belong to a new one."""
        cut = self.plateaus.counters.cut_short - self._cut_short_seen
        if cut:
            self.extractor.skip("plateau cut short", cut)
            self._cut_short_seen = self.plateaus.counters.cut_short
        out = CycleInput(joint=self.joint, cycle=cycle, t=self.last_tick / self.rate_hz,
                         friction=self.extractor.end_cycle(), load_mean=self._load.mean(),
                         load_std=self._load.last_spread(), motor_temperature=self._temperature.mean(),
                         partial=partial)
        self._load, self._temperature = _Mean(), _Mean()
        self.closed += 1
        return out

    def discard_cycle(self) -> None:
        """Drop the open cycle's data (a cycle already published before a restart)."""
        self.extractor.end_cycle()
        self._load, self._temperature = _Mean(), _Mean()

    def counters(self) -> dict[str, object]:
        return {"segmentation": self.plateaus.counters.as_dict(), "skipped": dict(self.extractor.totals)}

    def state_dict(self) -> dict[str, object]:
        """Only counters: open cycles are not carried across a restart."""
        return {"plateaus": self.plateaus.state_dict(), "skipped_totals": dict(self.extractor.totals),
                "closed": self.closed}

    def load_state(self, state: dict[str, object]) -> None:
        plateaus = state.get("plateaus")
        if isinstance(plateaus, dict):
            self.plateaus = PlateauDetector.from_state(self.plateaus.config, plateaus, self.rate_hz)
            self._cut_short_seen = self.plateaus.counters.cut_short
        closed = state.get("closed")
        if isinstance(closed, int) and closed >= 0:
            self.closed = closed
        totals = state.get("skipped_totals")
        if isinstance(totals, dict):
            self.extractor.totals.update({str(k): int(v) for k, v in totals.items() if isinstance(v, int)})
