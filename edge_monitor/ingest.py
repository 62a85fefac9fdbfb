"""Ingest: raw frame blocks → decode → E2E checks → per-joint sample blocks split by cycle.

Works on numpy blocks of frames (``ids``, ``data`` (n, 8), ``dlc``, ``timestamps``), the same in
the live loop and in replay. Frames failing decoding or E2E checks are excluded and counted,
never averaged in. The motor-state counter (controller tick mod 256) is unwrapped per joint into a
monotone controller tick; controller time = tick / rate. Every sample is labelled with the cycle and
segment of the controller status frame in force when it arrived (stream order).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Iterator

import numpy as np
from numpy.typing import NDArray

from protocol.e2e import E2EReceiver, E2EStatus
from protocol.frames import (
    CYCLE_MODULUS,
    MOTOR_COUNTER_MODULUS,
    DecodeErrorKind,
    FrameKind,
    decode_block,
)

_USABLE = (int(E2EStatus.OK), int(E2EStatus.OK_SOME_LOST))


@dataclass
class JointSamples:
    """Usable samples of one joint within one cycle run of a block, in stream order."""

    tick: NDArray[np.int64]
    speed: NDArray[np.float64]      # rad/s, motor side
    torque: NDArray[np.float64]     # fraction of max. joint torque
    segment: NDArray[np.int64]      # controller segment code in force (-1: unknown)


@dataclass
class CycleRun:
    """A maximal run of rows of a block under one controller cycle number (``None``: unknown)."""

    cycle: int | None
    samples: dict[int, JointSamples]
    load_estimates: list[tuple[int, float, float]]     # (joint, μl, σl)
    starts_at_boundary: bool | None = None              # first run of a cycle: was its start seen?


@dataclass
class IngestBlock:
    runs: list[CycleRun] = field(default_factory=list)

    def cycle_runs(self) -> Iterator[CycleRun]:
        return iter(self.runs)


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


class Ingest:
    """Stateful frame-block ingest for one controller."""

    def __init__(self, rate_hz: float = 500.0, joints: tuple[int, ...] | None = None,
                 e2e: E2EReceiver | None = None) -> None:
        self.rate_hz = rate_hz
        self.joints = None if joints is None else frozenset(joints)
        self.e2e = e2e or E2EReceiver()
        self.c = IngestCounters()
        self._cycle: int | None = None        # unwrapped cycle in force
        self._cycle_raw: int | None = None
        self._segment = -1                    # segment in force
        self._carry_cycle = -1                # cycle label in force at the end of the last block
        self._status_tick: int | None = None  # last controller tick from the status frame
        self._last_counter: dict[int, int] = {}
        self._last_tick: dict[int, int] = {}

    # ------------------------------------------------------------------ public
    def counters(self) -> dict[str, int]:
        return dict(self.c.__dict__)

    def process(self, ids: NDArray, data: NDArray, dlc: NDArray, timestamps: NDArray) -> IngestBlock:
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
        motor = usable & (dec.kind == FrameKind.MOTOR_STATE)
        if self.joints is not None:
            keep = np.isin(dec.joint, list(self.joints))
            self.c.joint_filtered += int((motor & ~keep).sum())
            motor &= keep
        ticks = self._unwrap_ticks(dec, motor)
        jstatus = usable & (dec.kind == FrameKind.JOINT_STATUS)
        return IngestBlock(self._split_runs(dec, motor, ticks, jstatus, row_cycle, row_segment, first_seen))

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
        """Forward-fill the cycle (unwrapped) and segment of usable status frames over all rows."""
        n = len(dec)
        status_rows = np.flatnonzero(usable & (dec.kind == FrameKind.CONTROLLER_STATUS))
        cycles = np.empty(status_rows.size, dtype=np.int64)
        first_seen: dict[int, bool] = {}
        for i, r in enumerate(status_rows):           # a few status frames per block: Python is fine
            raw = int(dec.cycle[r])
            seg = int(dec.segment[r])
            if self._cycle_raw is None:
                self._cycle = raw
                first_seen[raw] = seg <= 1        # the start of the first cycle seen: segment 0 or 1
            elif raw != self._cycle_raw:
                step = (raw - self._cycle_raw) % CYCLE_MODULUS
                if step < CYCLE_MODULUS // 2:
                    self._cycle += step
                else:                                # cycle counter went back: controller restart
                    self._cycle = raw if raw > self._cycle else self._cycle + 1
                first_seen[self._cycle] = True
            self._cycle_raw = raw
            cycles[i] = self._cycle
            self._status_tick = int(dec.status_tick[r])
        idx = np.full(n, -1, dtype=np.int64)
        idx[status_rows] = np.arange(status_rows.size)
        np.maximum.accumulate(idx, out=idx)
        segments = dec.segment[status_rows].astype(np.int64)
        row_cycle = np.where(idx >= 0, cycles[np.maximum(idx, 0)] if cycles.size else -1, self._carry_cycle)
        row_segment = np.where(idx >= 0, segments[np.maximum(idx, 0)] if segments.size else -1, self._segment)
        if status_rows.size:
            self._carry_cycle = int(cycles[-1])
            self._segment = int(segments[-1])
        return row_cycle.astype(np.int64), row_segment.astype(np.int64), first_seen

    def _unwrap_ticks(self, dec, motor: NDArray) -> NDArray[np.int64]:
        """Per joint, unwrap the 8-bit tick counter into a monotone controller tick."""
        ticks = np.full(len(dec), -1, dtype=np.int64)
        rows = np.flatnonzero(motor)
        if rows.size == 0:
            return ticks
        joints = dec.joint[rows]
        for joint in np.unique(joints):
            jr = rows[joints == joint]
            t8 = dec.counter[jr].astype(np.int64)
            j = int(joint)
            if j in self._last_counter:
                base, prev = self._last_tick[j], self._last_counter[j]
            else:
                anchor = self._status_tick if self._status_tick is not None else int(t8[0])
                base = anchor + ((int(t8[0]) - anchor + 128) % MOTOR_COUNTER_MODULUS) - 128
                prev = int(t8[0])
            steps = np.diff(t8, prepend=prev) % MOTOR_COUNTER_MODULUS
            full = base + np.cumsum(steps)
            ticks[jr] = full
            self._last_tick[j], self._last_counter[j] = int(full[-1]), int(t8[-1])
        return ticks

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
            loads = [(int(dec.joint[r]), float(dec.load_estimate[r]), float(dec.load_std[r])) for r in js]
            runs.append(CycleRun(cycle=None if cyc < 0 else cyc, samples=samples, load_estimates=loads,
                                 starts_at_boundary=first_seen.get(cyc)))
        return runs
