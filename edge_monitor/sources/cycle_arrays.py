"""Whole cycles of per-joint arrays as a source: the simulator's cycle-level mode
(``sim_controller.cycle_mode.CycleSignals``), without encoding, checking and decoding frames.

:class:`CycleArraySource` labels each cycle's samples with the controller's cycle and segment exactly as
:class:`~edge_monitor.sources.ingest.Ingest` labels frames — a joint sample belongs to the status frame
sent before it, and the status frame of a tick follows that tick's joint samples — so the agent fed its
blocks (``Agent.update_ingested``, :mod:`edge_monitor.offline.fast_path`) computes the per-cycle quantities
of ``sim-controller record`` + ``edge-monitor replay`` with the same seed (tests/test_fast_path.py). It reads
its input through :class:`CycleArrays` (what it needs of a cycle), so the agent's side imports nothing of
the simulator.
"""

from __future__ import annotations

from typing import Protocol, Sequence

import numpy as np
from numpy.typing import NDArray

from edge_monitor.sources.samples import CycleRun, IngestBlock, JointSamples, JointStatusBlock


class JointArrays(Protocol):
    """One joint's samples in a cycle: speed [rad/s] and torque [fraction of T_ref] per tick; load
    estimate, its σl [fraction of T_ref] and motor temperature [°C] per status frame."""

    @property
    def joint(self) -> int: ...
    @property
    def torque(self) -> NDArray[np.float64]: ...
    @property
    def speed(self) -> NDArray[np.float64]: ...
    @property
    def load_estimate(self) -> NDArray[np.float64]: ...
    @property
    def load_std(self) -> NDArray[np.float64]: ...
    @property
    def motor_temperature(self) -> NDArray[np.float64]: ...


class CycleArrays(Protocol):
    """One controller cycle: its number, the controller ticks of the samples, the ticks and segment codes of
    its status frames, and every joint's arrays."""

    @property
    def cycle(self) -> int: ...
    @property
    def ticks(self) -> NDArray[np.int64]: ...
    @property
    def status_ticks(self) -> NDArray[np.int64]: ...
    @property
    def status_segments(self) -> NDArray[np.int64]: ...
    @property
    def joints(self) -> Sequence[JointArrays]: ...


class CycleArraySource:
    """Cycles of arrays in, one :class:`IngestBlock` per cycle out (see the module docstring)."""

    def __init__(self) -> None:
        self._previous: tuple[int, int] | None = None     # (cycle, last segment) of the previous cycle

    def update(self, cycle: CycleArrays) -> IngestBlock:
        """The labelled samples of one cycle: the samples before its first status frame still belong to the
        previous cycle (its last segment), the rest to this one."""
        head = cycle.ticks <= cycle.status_ticks[0]        # before this cycle's first status frame
        runs = []
        if head.any():
            previous, segment = self._previous if self._previous is not None else (None, -1)
            runs.append(_run(cycle, head, previous, np.full(int(head.sum()), segment), {}))
        body = ~head
        governing = np.searchsorted(cycle.status_ticks, cycle.ticks[body], side="left") - 1
        status = {j.joint: JointStatusBlock(j.load_estimate, j.load_std, j.motor_temperature) for j in cycle.joints}
        runs.append(_run(cycle, body, cycle.cycle, cycle.status_segments[governing], status))
        self._previous = (cycle.cycle, int(cycle.status_segments[-1]))
        return IngestBlock(runs)


def _run(cycle: CycleArrays, rows: NDArray[np.bool_], label: int | None, segment: NDArray[np.int64],
         status: dict[int, JointStatusBlock]) -> CycleRun:
    samples = {j.joint: JointSamples(tick=cycle.ticks[rows], speed=j.speed[rows], torque=j.torque[rows],
                                     segment=segment.astype(np.int64)) for j in cycle.joints}
    return CycleRun(cycle=label, samples=samples, joint_status=status,
                    starts_at_boundary=True if label == cycle.cycle else None)
