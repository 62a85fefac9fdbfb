"""Decoded samples of a foreign source → labelled :class:`~edge_monitor.pipeline.samples.IngestBlock` s.

Times [s] become controller ticks at the agent's ``rate_hz`` (tick = round((t − t₀)·rate), t₀ the first
time seen). Samples wait in a buffer until the labeller's horizon has passed them (a plateau is known
only when it ends), bounded by ``max_pending_s`` (older samples are then released as they are labelled
and the release is counted). Samples before the first cycle found are dropped and counted
(``before_first_cycle``): the agent publishes whole cycles only.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import NDArray

from edge_monitor.pipeline.cycle_labels import CycleLabeller, Marks
from edge_monitor.pipeline.samples import CycleRun, DecodedSamples, IngestBlock, JointSamples, JointStatusBlock


@dataclass
class _Pending:
    """Buffered columns of one joint (samples) or one joint's status entries, in time order."""

    tick: list[NDArray[np.int64]] = field(default_factory=list)
    a: list[NDArray[np.float64]] = field(default_factory=list)
    b: list[NDArray[np.float64]] = field(default_factory=list)

    def add(self, tick: NDArray[np.int64], a: NDArray[np.float64], b: NDArray[np.float64]) -> None:
        if tick.size:
            self.tick.append(tick)
            self.a.append(a)
            self.b.append(b)

    def take_before(self, horizon: float) -> tuple[NDArray[np.int64], NDArray[np.float64], NDArray[np.float64]]:
        if not self.tick:
            return np.empty(0, np.int64), np.empty(0), np.empty(0)
        tick, a, b = np.concatenate(self.tick), np.concatenate(self.a), np.concatenate(self.b)
        cut = int(np.searchsorted(tick, horizon, side="left")) if math.isfinite(horizon) else tick.size
        self.tick, self.a, self.b = ([tick[cut:]], [a[cut:]], [b[cut:]]) if cut < tick.size else ([], [], [])
        return tick[:cut], a[:cut], b[:cut]

    def __len__(self) -> int:
        return sum(t.size for t in self.tick)


class SampleStream:
    """Labels decoded samples with cycles and segments (see the module docstring)."""

    def __init__(self, labeller: CycleLabeller, rate_hz: float, reference_joint: int,
                 max_pending_s: float = 120.0) -> None:
        self.labeller = labeller
        self.rate_hz = rate_hz
        self.reference_joint = reference_joint
        self.max_pending = int(max_pending_s * rate_hz)
        self._t0: float | None = None
        self._latest = -1
        self._samples: dict[int, _Pending] = {}
        self._status: dict[int, _Pending] = {}
        self._first_cycle_seen: set[int] = set()
        self.before_first_cycle = 0
        self.forced_release = 0

    def ticks(self, time: NDArray[np.float64]) -> NDArray[np.int64]:
        if time.size and self._t0 is None:
            self._t0 = float(time[0])
        t0 = self._t0 if self._t0 is not None else 0.0
        return np.rint((np.asarray(time, dtype=float) - t0) * self.rate_hz).astype(np.int64)

    def update(self, decoded: DecodedSamples) -> IngestBlock:
        firsts = [c.time[0] for c in decoded.joints.values() if c.time.size]
        firsts += [c.time[0] for c in decoded.status.values() if c.time.size]
        if firsts and self._t0 is None:
            self._t0 = float(min(firsts))
        ref_tick, ref_speed = np.empty(0, np.int64), np.empty(0)
        for joint, cols in decoded.joints.items():
            tick = self.ticks(cols.time)
            self._samples.setdefault(joint, _Pending()).add(tick, cols.speed, cols.torque)
            if tick.size:
                self._latest = max(self._latest, int(tick[-1]))
            if joint == self.reference_joint:
                ref_tick, ref_speed = tick, cols.speed
        for joint, st in decoded.status.items():
            self._status.setdefault(joint, _Pending()).add(self.ticks(st.time), st.load, st.temperature)
        marks: Marks = {name: (self.ticks(t), v) for name, (t, v) in decoded.marks.items()}
        horizon = self.labeller.update(ref_tick, ref_speed, marks, self._latest)
        if self._latest - horizon > self.max_pending:
            self.forced_release += 1
            horizon = self._latest - self.max_pending
        return self._release(horizon)

    def flush(self) -> IngestBlock:
        """End of stream: every buffered sample, labelled as far as the motion tells."""
        self.labeller.flush()
        return self._release(math.inf)

    def _release(self, horizon: float) -> IngestBlock:
        changes = self.labeller.changes
        if not changes:
            ch_tick, ch_cycle, ch_segment = np.empty(0, np.int64), np.empty(0, np.int64), np.empty(0, np.int64)
        else:
            ch_tick, ch_cycle, ch_segment = (np.asarray(c, dtype=np.int64) for c in zip(*changes))
        per_cycle: dict[int, CycleRun] = {}

        def label(tick: NDArray[np.int64]) -> tuple[NDArray[np.int64], NDArray[np.int64]]:
            at = np.searchsorted(ch_tick, tick, side="right") - 1
            known = at >= 0
            cycle = np.where(known, ch_cycle[np.maximum(at, 0)] if ch_cycle.size else -1, -1)
            segment = np.where(known, ch_segment[np.maximum(at, 0)] if ch_segment.size else -1, -1)
            return cycle, segment

        for joint, pending in self._samples.items():
            tick, speed, torque = pending.take_before(horizon)
            cycle, segment = label(tick)
            self.before_first_cycle += int((cycle < 0).sum())
            for c in np.unique(cycle[cycle >= 0]).tolist():
                rows = cycle == c
                run = per_cycle.setdefault(c, self._run(c))
                run.samples[joint] = JointSamples(tick[rows], speed[rows], torque[rows], segment[rows])
        for joint, pending in self._status.items():
            tick, load, temperature = pending.take_before(horizon)
            cycle, _ = label(tick)
            for c in np.unique(cycle[cycle >= 0]).tolist():
                rows = cycle == c
                run = per_cycle.setdefault(c, self._run(c))
                run.joint_status[joint] = JointStatusBlock(load[rows], np.full(int(rows.sum()), np.nan),
                                                           temperature[rows])
        self._trim(horizon)
        return IngestBlock([per_cycle[c] for c in sorted(per_cycle)])

    def _run(self, cycle: int) -> CycleRun:
        first = cycle not in self._first_cycle_seen
        self._first_cycle_seen.add(cycle)
        if len(self._first_cycle_seen) > 4:
            self._first_cycle_seen = set(sorted(self._first_cycle_seen)[-2:])
        return CycleRun(cycle=cycle, samples={}, joint_status={}, starts_at_boundary=True if first else None)

    def _trim(self, horizon: float) -> None:
        """Forget change points no pending sample can need (keep the one in force)."""
        changes = self.labeller.changes
        pending = [p.tick[0][0] for p in (*self._samples.values(), *self._status.values()) if p.tick]
        oldest = min(pending) if pending else horizon
        keep = 0
        for i, (tick, _, _) in enumerate(changes):
            if tick <= oldest:
                keep = i
        if keep:
            del changes[:keep]

    def pending_samples(self) -> int:
        return sum(len(p) for p in self._samples.values())

    def counters(self) -> dict[str, Any]:
        return {"method": self.labeller.method, "before_first_cycle": self.before_first_cycle,
                "forced_release": self.forced_release,
                **self.labeller.counters()}
