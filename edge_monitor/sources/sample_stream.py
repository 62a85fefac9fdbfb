"""Decoded samples of a foreign source → labelled :class:`~edge_monitor.sources.samples.IngestBlock` s.

Times [s] become controller ticks at the agent's ``rate_hz`` (tick = round((t − t₀)·rate), t₀ the first
time seen). Samples wait in a buffer until the labeller's horizon has passed them (a plateau is known
only when it ends), bounded by ``max_pending_s`` (older samples are then released as they are labelled
and the release is counted). Samples before the first cycle found are dropped and counted
(``before_first_cycle``): the agent publishes whole cycles only.

A sample no robot can give is dropped and counted in ``samples_dropped`` by reason: ``not_finite``
(speed or torque NaN or infinite: an empty trace cell, an overflowing scale), ``out_of_range`` (beyond
:data:`PLAUSIBLE`: a wrong unit, scale or reference torque), ``bad_time`` (a time that is not finite or
beyond :data:`MAX_TIME_S`, or more than :data:`MAX_SPAN_S` from the first), ``time_backwards``
(earlier than the joint's last sample: a shuffled or concatenated trace) and ``pending_full`` (more
than 4 × ``max_pending_s`` of samples waiting for a label: times that do not advance). So memory and
work per sample stay bounded whatever the times.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import NDArray

from edge_monitor.sources.cycle_labels import CycleLabeller, Marks
from edge_monitor.sources.samples import CycleRun, DecodedSamples, IngestBlock, JointSamples, JointStatusBlock
from protocol.mapping_limits import MAX_LEVEL_SPEED

#: Values beyond these are taken as a wrong unit, scale or reference torque (speed [rad/s, motor side],
#: torque and load [fraction of T_ref], temperature [°C]).
PLAUSIBLE = {"speed": MAX_LEVEL_SPEED, "torque": 3.0, "load": 3.0, "temperature": 200.0}
#: The longest time span a stream may cover [s] (ticks stay exact integers at any rate), and the
#: largest time any clock gives [s] (Unix time in ms read as s is 1.8e12): the first time within it is t₀.
MAX_SPAN_S, MAX_TIME_S = 1e9, 1e13
BAD_TICK = np.iinfo(np.int64).min
DROP_REASONS = ("not_finite", "out_of_range", "bad_time", "time_backwards", "pending_full")


def _usable(time: NDArray[np.float64]) -> NDArray[np.bool_]:
    with np.errstate(invalid="ignore"):
        return np.isfinite(time) & (np.abs(time) <= MAX_TIME_S)


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

    def drop_oldest(self, keep: int) -> int:
        """Forget all but the newest ``keep`` entries; how many were dropped."""
        surplus = len(self) - keep
        if surplus <= 0:
            return 0
        tick, a, b = np.concatenate(self.tick), np.concatenate(self.a), np.concatenate(self.b)
        self.tick, self.a, self.b = [tick[surplus:]], [a[surplus:]], [b[surplus:]]
        return surplus


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
        self.dropped = dict.fromkeys(DROP_REASONS, 0)
        self._last_tick: dict[int, int] = {}

    def ticks(self, time: NDArray[np.float64]) -> NDArray[np.int64]:
        """Ticks of ``time`` [s]; times that are not finite or beyond :data:`MAX_SPAN_S` from the first
        become :data:`BAD_TICK` (callers drop them)."""
        time = np.asarray(time, dtype=float)
        if self._t0 is None:
            usable = time[_usable(time)]
            if usable.size:
                self._t0 = float(usable[0])
        t0 = self._t0 if self._t0 is not None else 0.0
        with np.errstate(invalid="ignore", over="ignore"):
            span = time - t0
            good = _usable(time) & np.isfinite(span) & (np.abs(span) <= MAX_SPAN_S)
        return np.where(good, np.rint(np.where(good, span, 0.0) * self.rate_hz).astype(np.int64), BAD_TICK)

    def _valid_time(self, key: int, tick: NDArray[np.int64]) -> NDArray[np.bool_]:
        """Rows with a usable time not earlier than the last of stream ``key``; counts the others."""
        good = tick != BAD_TICK
        self.dropped["bad_time"] += int((~good).sum())
        last = self._last_tick.get(key, BAD_TICK)
        reached = np.maximum.accumulate(np.concatenate(([last], tick)))[:-1]
        forward = good & (tick >= reached)
        self.dropped["time_backwards"] += int((good & ~forward).sum())
        if forward.any():
            self._last_tick[key] = max(last, int(tick[forward].max()))
        return forward

    def _valid_values(self, speed: NDArray[np.float64], torque: NDArray[np.float64]) -> NDArray[np.bool_]:
        finite = np.isfinite(speed) & np.isfinite(torque)
        plausible = finite & (np.abs(np.where(finite, speed, 0.0)) <= PLAUSIBLE["speed"]) \
            & (np.abs(np.where(finite, torque, 0.0)) <= PLAUSIBLE["torque"])
        self.dropped["not_finite"] += int((~finite).sum())
        self.dropped["out_of_range"] += int((finite & ~plausible).sum())
        return plausible

    def update(self, decoded: DecodedSamples) -> IngestBlock:
        times = [c.time for c in decoded.joints.values()] + [c.time for c in decoded.status.values()]
        firsts = [float(t[_usable(t)][0]) for t in times if _usable(t).any()]
        if firsts and self._t0 is None:
            self._t0 = min(firsts)
        ref_tick, ref_speed = np.empty(0, np.int64), np.empty(0)
        for joint, cols in decoded.joints.items():
            tick = self.ticks(cols.time)
            ok = self._valid_values(cols.speed, cols.torque)
            ok[ok] = self._valid_time(joint, tick[ok])
            tick, speed = tick[ok], cols.speed[ok]
            pending = self._samples.setdefault(joint, _Pending())
            pending.add(tick, speed, cols.torque[ok])
            self.dropped["pending_full"] += pending.drop_oldest(4 * self.max_pending)
            if tick.size:
                self._latest = max(self._latest, int(tick[-1]))
            if joint == self.reference_joint:
                ref_tick, ref_speed = tick, speed
        for joint, st in decoded.status.items():
            tick = self.ticks(st.time)
            ok = self._valid_time(-1 - joint, tick)
            pending = self._status.setdefault(joint, _Pending())
            pending.add(tick[ok], st.load[ok], st.temperature[ok])
            self.dropped["pending_full"] += pending.drop_oldest(4 * self.max_pending)
        marks: Marks = {}
        for name, (t, v) in decoded.marks.items():
            tick = self.ticks(t)
            ok = (tick != BAD_TICK) & np.isfinite(v)
            marks[name] = (tick[ok], v[ok])
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
