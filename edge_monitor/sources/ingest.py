"""Ingest: raw frame blocks → decode → E2E checks → per-joint sample blocks split by cycle.

Works on numpy blocks of frames (``ids``, ``data`` (n, 8), ``dlc``, ``timestamps``), the same in
the live loop and in replay. Frames failing decoding or E2E checks are excluded and counted,
never averaged in. The motor-state counter (controller tick mod 256) is unwrapped per joint into a
monotone controller tick; controller time = tick / rate. Every sample is labelled with the cycle and
segment of the controller status frame in force when it arrived (stream order); which status frames
may change the cycle (progress, a confirmed controller restart, not a jump of a reordered or replayed
stream) is :mod:`edge_monitor.sources.cycle_numbering`. Its output is the sample interface of
:mod:`edge_monitor.sources.samples`, which every source produces.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from edge_monitor.sources.cycle_numbering import MAX_CYCLE_STEP, CycleNumbering, tick_step
from edge_monitor.sources.samples import CycleRun, IngestBlock, JointSamples, JointStatusBlock, SourceConfig
from protocol.e2e import E2EReceiver, E2EStatus
from protocol.frames import (
    MOTOR_COUNTER_MODULUS,
    DecodeErrorKind,
    FrameKind,
    decode_block,
)

__all__ = ["MAX_CYCLE_STEP", "CycleRun", "Ingest", "IngestBlock", "IngestCounters", "JointSamples",
           "JointStatusBlock"]

_USABLE = (int(E2EStatus.OK), int(E2EStatus.OK_SOME_LOST))


@dataclass
class IngestCounters:
    frames_total: int = 0
    frames_ok: int = 0
    crc_errors: int = 0
    counter_lost: int = 0
    repeated: int = 0
    wrong_sequence: int = 0
    unknown_id: int = 0
    malformed: int = 0
    joint_filtered: int = 0
    cycle_jumps: int = 0            # status frames whose cycle or tick jumped implausibly: not followed
    controller_restarts: int = 0    # controller restarts taken (confirmed by the next status frame)


class Ingest:
    """Stateful frame-block ingest for one controller."""

    def __init__(self, rate_hz: float = 500.0, joints: tuple[int, ...] | None = None,
                 e2e: E2EReceiver | None = None) -> None:
        self.rate_hz = rate_hz
        self.joints = None if joints is None else frozenset(joints)
        self.e2e = e2e or E2EReceiver()
        self.c = IngestCounters()
        self.numbering = CycleNumbering(rate_hz)
        self._segment = -1                    # segment in force
        self._restarted_into: set[int] = set()     # cycles of this block entered by a controller restart
        self._status_tick: int | None = None  # last controller tick from the status frame (unwrapped)
        self._status_tick_raw: int | None = None
        self._last_counter: dict[int, int] = {}
        self._last_tick: dict[int, int] = {}

    @classmethod
    def for_config(cls, config: SourceConfig) -> Ingest:
        """The ingest of our own frames for an agent's ``config`` (its default sample source)."""
        return cls(rate_hz=config.rate_hz, joints=config.joints)

    # ------------------------------------------------------------------ public
    def counters(self) -> dict[str, int]:
        self.c.cycle_jumps, self.c.controller_restarts = self.numbering.jumps, self.numbering.restarts
        return dict(self.c.__dict__)

    def update(self, ids: NDArray, data: NDArray, dlc: NDArray, timestamps: NDArray) -> IngestBlock:
        """Decode, check and split one block of frames (``data`` (n, 8) uint8, timestamps in s)."""
        n = int(np.asarray(ids).shape[0])
        if n == 0:
            return IngestBlock()
        dec = decode_block(ids, data, dlc)
        statuses, lost = self.e2e.check_block(dec.arbitration_id, dec.counter, dec.valid,
                                              np.asarray(timestamps, dtype=float))
        statuses = np.asarray(statuses)
        usable = dec.valid & np.isin(statuses, _USABLE)
        self._count(dec, statuses, np.asarray(lost), usable)
        row_cycle, row_segment, first_seen = self._label_rows(dec, usable)
        row_tick = self._status_ticks(dec)
        motor = usable & (dec.kind == FrameKind.MOTOR_STATE)
        jstatus = usable & (dec.kind == FrameKind.JOINT_STATUS)
        if self.joints is not None:         # joints outside the configured set: counted, never monitored
            keep = np.isin(dec.joint, list(self.joints))
            self.c.joint_filtered += int(((motor | jstatus) & ~keep).sum())
            motor &= keep
            jstatus &= keep
        ticks = self._unwrap_ticks(dec, motor, row_tick)
        runs = self._split_runs(dec, motor, ticks, jstatus, row_cycle, row_segment, first_seen)
        _stamp_runs(runs, np.asarray(timestamps, dtype=float))
        return IngestBlock(runs)

    # ------------------------------------------------------------------ internals
    def _count(self, dec, statuses: NDArray, lost: NDArray, usable: NDArray) -> None:
        c = self.c
        c.frames_total += len(dec)
        c.frames_ok += int(usable.sum())
        err = dec.error
        c.crc_errors += int((err == DecodeErrorKind.CRC).sum())
        c.unknown_id += int((err == DecodeErrorKind.UNKNOWN_ID).sum())
        c.malformed += int(((err == DecodeErrorKind.WRONG_DLC) | (err == DecodeErrorKind.BAD_VALUE)).sum())
        c.repeated += int((statuses == E2EStatus.REPEATED).sum())
        c.wrong_sequence += int((statuses == E2EStatus.WRONG_SEQUENCE).sum())
        c.counter_lost += int(lost[lost > 0].sum())

    def _label_rows(self, dec, usable: NDArray) -> tuple[NDArray[np.int64], NDArray[np.int64], dict[int, bool]]:
        """Forward-fill the cycle (unwrapped) and segment of the usable status frames the cycle
        numbering takes over all rows (-1 where none is known yet). A restart confirmed in this block
        takes effect from its first status frame."""
        n = len(dec)
        first_seen: dict[int, bool] = {}
        self._restarted_into.clear()
        numbering = self.numbering
        in_force = -1 if numbering.cycle is None else numbering.cycle      # before this block's status frames
        taken: list[int] = []
        cycles: list[int] = []
        waiting: list[int] = []                       # rows not taken since the last one taken
        for r in np.flatnonzero(usable & (dec.kind == FrameKind.CONTROLLER_STATUS)).tolist():
            cycle = numbering.update(int(dec.cycle[r]), int(dec.segment[r]), int(dec.status_tick[r]), first_seen)
            if cycle is None:                         # a jump, or a discontinuity to be confirmed
                waiting.append(r)
                continue
            if numbering.restarted:
                self._restarted_into.add(cycle)
            back = waiting[len(waiting) - numbering.taken_back:] if numbering.taken_back else []
            taken += back + [r]                       # a confirmed discontinuity: from its first frame on
            cycles += [cycle] * (len(back) + 1)
            waiting = []
        status_rows = np.asarray(taken, dtype=np.int64)
        cycle_of = np.asarray(cycles, dtype=np.int64)
        at, known = _forward_index(n, status_rows)
        segments = dec.segment[status_rows].astype(np.int64)
        row_cycle = np.where(known, cycle_of[at] if cycle_of.size else -1, in_force)
        row_segment = np.where(known, segments[at] if segments.size else -1, self._segment)
        if status_rows.size:
            self._segment = int(segments[-1])
        return row_cycle.astype(np.int64), row_segment.astype(np.int64), first_seen

    def _status_ticks(self, dec) -> NDArray[np.int64]:
        """Forward-fill the (unwrapped) controller tick of every CRC-valid status frame over all rows.
        The tick is absolute, so it is used even when the frame's alive counter is out of sequence
        (the first frame after a long silence): that re-anchors the motor ticks at once."""
        rows = np.flatnonzero(dec.valid & (dec.kind == FrameKind.CONTROLLER_STATUS))
        carry = -1 if self._status_tick is None else self._status_tick      # in force before this block
        ticks = np.array([self._update_status_tick(int(dec.status_tick[r])) for r in rows], dtype=np.int64)
        at, known = _forward_index(len(dec), rows)
        return np.where(known, ticks[at] if ticks.size else -1, carry).astype(np.int64)

    def _update_status_tick(self, raw: int) -> int:
        """Unwrap the 24-bit controller tick of the status frame (a backward step is a restart)."""
        if self._status_tick is None or self._status_tick_raw is None:
            full = raw
        else:
            step = tick_step(self._status_tick_raw, raw)
            full = raw if step is None else self._status_tick + step
        self._status_tick_raw, self._status_tick = raw, full
        return full

    def _unwrap_ticks(self, dec, motor: NDArray, row_tick: NDArray[np.int64]) -> NDArray[np.int64]:
        """Controller tick of each motor sample: anchored to the status-frame tick in force (sent every
        10 ticks, so exact across any gap); before the first status frame, the 8-bit counter is
        unwrapped per joint (exact across gaps of < 256 frames)."""
        ticks = np.full(len(dec), -1, dtype=np.int64)
        rows = np.flatnonzero(motor)
        if rows.size == 0:
            return ticks
        joints = dec.joint[rows]
        for joint in np.unique(joints):
            jr = rows[joints == joint]
            t8 = dec.counter[jr].astype(np.int64)
            j = int(joint)
            anchor = row_tick[jr]
            anchored = anchor >= 0
            full = np.empty(jr.size, dtype=np.int64)
            full[anchored] = anchor[anchored] + (t8[anchored] - anchor[anchored] + 128) % MOTOR_COUNTER_MODULUS - 128
            loose = np.flatnonzero(~anchored)
            if loose.size:
                base = self._last_tick.get(j, int(t8[loose[0]]))
                prev = self._last_counter.get(j, int(t8[loose[0]]))
                full[loose] = base + np.cumsum(np.diff(t8[loose], prepend=prev) % MOTOR_COUNTER_MODULUS)
            ticks[jr] = full
            self._last_tick[j], self._last_counter[j] = int(full[-1]), int(t8[-1])
        return ticks

    # ------------------------------------------------------------------ persistence
    def state_dict(self) -> dict:
        """Cycle and tick unwrapping state: a restarted agent keeps its cycle numbering."""
        return {**self.numbering.state_dict(), "status_tick": self._status_tick,
                "status_tick_raw": self._status_tick_raw}

    def load_state(self, state: dict) -> None:
        self.numbering.load_state(state)
        self._status_tick = state.get("status_tick")
        self._status_tick_raw = state.get("status_tick_raw")

    def _split_runs(self, dec, motor, ticks, jstatus, row_cycle, row_segment, first_seen) -> list[CycleRun]:
        n = len(dec)
        change = np.flatnonzero(np.diff(row_cycle) != 0) + 1
        starts = np.concatenate([[0], change])
        ends = np.append(change, n)
        runs: list[CycleRun] = []
        for s, e in zip(starts, ends):
            cyc = int(row_cycle[s])
            sl = slice(s, e)
            m = np.flatnonzero(motor[sl]) + s
            samples: dict[int, JointSamples] = {}
            if m.size:
                mj = dec.joint[m]
                for joint in np.unique(mj):
                    r = m[mj == joint]
                    samples[int(joint)] = JointSamples(tick=ticks[r], speed=dec.speed[r], torque=dec.torque[r],
                                                       segment=row_segment[r])
            js = np.flatnonzero(jstatus[sl]) + s
            status = {int(joint): JointStatusBlock(dec.load_estimate[rows], dec.load_std[rows],
                                                   dec.motor_temperature[rows])
                      for joint in np.unique(dec.joint[js]) for rows in (js[dec.joint[js] == joint],)}
            runs.append(CycleRun(cycle=None if cyc < 0 else cyc, samples=samples, joint_status=status,
                                 starts_at_boundary=first_seen.get(cyc),
                                 previous_cut=cyc in self._restarted_into, rows=int(e - s)))
        return runs


def _stamp_runs(runs: list[CycleRun], timestamps: NDArray[np.float64]) -> None:
    """Give each run the timestamp of its last frame (runs cover the block's rows in order)."""
    end = 0
    for run in runs:
        end += run.rows
        run.last_time = float(timestamps[end - 1]) if end else None


def _forward_index(n: int, rows: NDArray[np.int64]) -> tuple[NDArray[np.int64], NDArray[np.bool_]]:
    """For each of ``n`` rows: the index into ``rows`` of the last listed row at or before it."""
    idx = np.full(n, -1, dtype=np.int64)
    idx[rows] = np.arange(rows.size)
    np.maximum.accumulate(idx, out=idx)
    return np.maximum(idx, 0), idx >= 0
