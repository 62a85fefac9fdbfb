"""Receiver-side end-to-end check: alive counter + CRC result per CAN identifier.

Per identifier, in the spirit of the AUTOSAR E2E profile 1 check and state machine.

Classification of one frame with counter ``c`` against the reference counter ``ref`` (the last
accepted counter), ``d = (c - ref) mod M`` (M = 256 for MotorState ticks, 16 for status frames):

* CRC / decode failed                  -> ``ERROR``; nothing else changes.
* first frame of an identifier (INIT)  -> ``OK`` (lost 0); it becomes the reference.
* ``d == 0``                           -> ``REPEATED``; data not used, reference unchanged.
* ``1 <= d <= max_delta``              -> ``OK`` (d == 1) or ``OK_SOME_LOST`` (lost = d - 1);
  the reference moves to ``c``.
* otherwise (a jump beyond max_delta, or backwards: stale / reordered) -> ``WRONG_SEQUENCE``
  (lost = -1, unknown); data not used and the reference is **not** moved.  The counter is kept
  as a *resync candidate*: if the next frame continues the candidate (1 <= (c' - cand) mod M <=
  max_delta) and not the reference, the receiver resynchronises on it (status ``OK`` /
  ``OK_SOME_LOST`` relative to the candidate, counted in ``resyncs``).  So a controller restart
  or a long outage costs one frame, while a single stale frame never drags the reference back.
  (Two or more *consecutive* stale frames are indistinguishable from a restart by counters alone:
  the receiver resyncs on them and the live stream then costs one frame to resync back.)
* ``poll(now)``: an identifier whose last accepted frame is older than its timeout reports
  ``NO_NEW_DATA`` once per outage.

State machine per identifier: ``INIT`` -> ``VALID`` on the first accepted frame; ``VALID`` ->
``INVALID`` on ``ERROR``, ``WRONG_SEQUENCE`` or ``NO_NEW_DATA``; ``INVALID`` -> ``VALID`` after
``ok_to_valid`` consecutive accepted frames (``OK`` / ``OK_SOME_LOST``).  ``REPEATED`` leaves the
state and the run of accepted frames unchanged.  A frame's data is usable iff its status is
``OK`` or ``OK_SOME_LOST`` (see ``usable``).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from enum import Enum, IntEnum
from typing import Mapping

import numpy as np

from protocol.frames import CATALOGUE

DEFAULT_MAX_DELTA_8BIT = 16
DEFAULT_MAX_DELTA_4BIT = 3
DEFAULT_OK_TO_VALID = 2


class E2EStatus(IntEnum):
    """Check result of one frame (NO_NEW_DATA only from ``poll``)."""

    OK = 0
    OK_SOME_LOST = 1
    REPEATED = 2
    WRONG_SEQUENCE = 3
    ERROR = 4
    NO_NEW_DATA = 5


class E2EState(Enum):
    """Per-identifier state of the check state machine."""

    INIT = "init"
    VALID = "valid"
    INVALID = "invalid"


class E2EConfigError(ValueError):
    """Invalid receiver configuration (the message names the parameter)."""


def usable(statuses: np.ndarray) -> np.ndarray:
    """Mask of frames whose data may be used (status OK or OK_SOME_LOST)."""
    return np.asarray(statuses) <= E2EStatus.OK_SOME_LOST


_OK, _OK_SOME_LOST, _ERROR = int(E2EStatus.OK), int(E2EStatus.OK_SOME_LOST), int(E2EStatus.ERROR)

STAT_KEYS = ("frames", "ok", "some_lost", "lost_frames", "repeated", "wrong_sequence", "resyncs",
             "crc_errors", "unknown_id", "no_new_data")


@dataclass(slots=True)
class _IdState:
    modulus: int
    max_delta: int
    timeout_s: float
    state: E2EState = E2EState.INIT
    reference: int = -1  # last accepted counter, -1 before the first
    candidate: int = -1  # resync candidate, -1 when none
    ok_run: int = 0  # consecutive accepted frames (for INVALID -> VALID)
    last_accepted: float = -math.inf  # timestamp of the last accepted frame, s
    timed_out: bool = False


class E2EReceiver:
    """Per-identifier alive-counter / CRC check with statistics.

    timeout_s: default NO_NEW_DATA timeout (s); ``timeouts`` overrides it per arbitration ID.
    max_delta: largest accepted counter jump for the 8-bit MotorState ticks (default 16);
    max_delta_status: the same for the 4-bit status counters (default 3).
    ok_to_valid: consecutive accepted frames that bring an INVALID identifier back to VALID.
    """

    def __init__(
        self,
        timeout_s: float = 0.1,
        max_delta: int | None = None,
        *,
        max_delta_status: int | None = None,
        ok_to_valid: int = DEFAULT_OK_TO_VALID,
        timeouts: Mapping[int, float] | None = None,
    ) -> None:
        self._max_delta = {256: self._checked_delta("max_delta", max_delta, DEFAULT_MAX_DELTA_8BIT, 256),
                           16: self._checked_delta("max_delta_status", max_delta_status,
                                                   DEFAULT_MAX_DELTA_4BIT, 16)}
        if not (timeout_s > 0 and math.isfinite(timeout_s)):
            raise E2EConfigError(f"timeout_s: {timeout_s!r} must be a positive number of seconds")
        if int(ok_to_valid) < 1:
            raise E2EConfigError(f"ok_to_valid: {ok_to_valid!r} must be >= 1")
        self.timeout_s = float(timeout_s)
        self.ok_to_valid = int(ok_to_valid)
        self._timeouts = {int(k): float(v) for k, v in (timeouts or {}).items()}
        for arbitration_id, value in self._timeouts.items():
            if not value > 0:
                raise E2EConfigError(f"timeouts[0x{arbitration_id:X}]: {value!r} must be positive seconds")
        self._states: dict[int, _IdState] = {}
        self.stats: dict[str, int] = dict.fromkeys(STAT_KEYS, 0)

    @staticmethod
    def _checked_delta(name: str, value: int | None, default: int, modulus: int) -> int:
        if value is None:
            return default
        if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or not 1 <= value < modulus:
            raise E2EConfigError(f"{name}: {value!r} must be an integer 1 .. {modulus - 1}")
        return int(value)

    # -- per-identifier state ----------------------------------------------------------------

    def _state_for(self, arbitration_id: int) -> _IdState | None:
        st = self._states.get(arbitration_id)
        if st is None:
            frame_type = CATALOGUE.get(arbitration_id)
            if frame_type is None:
                return None
            modulus = frame_type.counter_modulus
            st = _IdState(modulus, self._max_delta[modulus], self._timeouts.get(arbitration_id, self.timeout_s))
            self._states[arbitration_id] = st
        return st

    def state(self, arbitration_id: int) -> E2EState:
        """Current state of an identifier (INIT if never seen)."""
        st = self._states.get(int(arbitration_id))
        return st.state if st is not None else E2EState.INIT

    def states(self) -> dict[int, E2EState]:
        """State of every identifier seen so far."""
        return {k: v.state for k, v in self._states.items()}

    def _invalidate(self, st: _IdState) -> None:
        if st.state is E2EState.VALID:
            st.state = E2EState.INVALID
        st.ok_run = 0

    def _accept(self, st: _IdState, counter: int, timestamp: float, runs: int = 1) -> None:
        st.reference = counter
        st.candidate = -1
        st.last_accepted = timestamp
        st.timed_out = False
        st.ok_run += runs
        if st.state is E2EState.INIT or (st.state is E2EState.INVALID and st.ok_run >= self.ok_to_valid):
            st.state = E2EState.VALID

    # -- checks ------------------------------------------------------------------------------

    def check(self, arbitration_id: int, counter: int, crc_ok: bool, timestamp: float) -> tuple[E2EStatus, int]:
        """Classify one frame -> (status, lost frames; -1 = unknown). Never raises on data."""
        self.stats["frames"] += 1
        st = self._state_for(int(arbitration_id))
        if st is None:
            self.stats["unknown_id"] += 1
            return E2EStatus.ERROR, 0
        return self._check_one(st, int(counter), bool(crc_ok), float(timestamp))

    def _check_one(self, st: _IdState, counter: int, crc_ok: bool, timestamp: float) -> tuple[E2EStatus, int]:
        stats = self.stats
        if not crc_ok or not 0 <= counter < st.modulus:
            stats["crc_errors"] += 1
            self._invalidate(st)
            return E2EStatus.ERROR, 0
        if st.reference < 0:
            self._accept(st, counter, timestamp)
            stats["ok"] += 1
            return E2EStatus.OK, 0
        delta = (counter - st.reference) % st.modulus
        if delta == 0:
            stats["repeated"] += 1
            return E2EStatus.REPEATED, 0
        if delta > st.max_delta and st.candidate >= 0:
            from_candidate = (counter - st.candidate) % st.modulus
            if 1 <= from_candidate <= st.max_delta:
                stats["resyncs"] += 1
                delta = from_candidate
        if delta > st.max_delta:
            stats["wrong_sequence"] += 1
            st.candidate = counter
            self._invalidate(st)
            return E2EStatus.WRONG_SEQUENCE, -1
        self._accept(st, counter, timestamp)
        if delta == 1:
            stats["ok"] += 1
            return E2EStatus.OK, 0
        stats["some_lost"] += 1
        stats["lost_frames"] += delta - 1
        return E2EStatus.OK_SOME_LOST, delta - 1

    def check_block(
        self, ids: np.ndarray, counters: np.ndarray, crc_ok: np.ndarray, timestamps: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray]:
        """Check n frames in arrival order -> (statuses int8[n] E2EStatus, lost int32[n]).

        Identical results to calling ``check`` row by row.  Rows are grouped per identifier;
        runs of in-sequence frames are classified with numpy, irregular frames one by one.
        """
        ids = np.asarray(ids, dtype=np.int64).reshape(-1)
        n = ids.shape[0]
        counters = np.asarray(counters, dtype=np.int64).reshape(n)
        crc_ok = np.asarray(crc_ok, dtype=bool).reshape(n)
        timestamps = np.asarray(timestamps, dtype=np.float64).reshape(n)
        statuses = np.empty(n, dtype=np.int8)
        lost = np.zeros(n, dtype=np.int32)
        if n == 0:
            return statuses, lost
        self.stats["frames"] += n
        order = np.argsort(ids, kind="stable")
        sorted_ids = ids[order]
        starts = np.concatenate(([0], np.flatnonzero(sorted_ids[1:] != sorted_ids[:-1]) + 1))
        sizes = np.diff(np.append(starts, n))
        states = [self._state_for(i) for i in sorted_ids[starts].tolist()]
        known = [st is not None for st in states]
        reference = np.array([st.reference if st else -1 for st in states], dtype=np.int64)
        modulus = np.array([st.modulus if st else 1 for st in states], dtype=np.int64)
        max_delta = np.array([st.max_delta if st else 0 for st in states], dtype=np.int64)

        # All groups at once: a group whose every frame follows its predecessor within max_delta
        # (and passed decoding) is "clean" and classified here; the others go row by row.
        sorted_counters = counters[order]
        previous = np.empty(n, dtype=np.int64)
        previous[1:] = sorted_counters[:-1]
        previous[starts] = reference
        group_of_row = np.repeat(np.arange(len(states)), sizes)
        delta = (sorted_counters - previous) % modulus[group_of_row]
        in_sequence = crc_ok[order] & (delta >= 1) & (delta <= max_delta[group_of_row])
        clean = np.logical_and.reduceat(in_sequence, starts) & (reference >= 0)
        sorted_status = np.where(delta == 1, _OK, _OK_SOME_LOST).astype(np.int8)
        sorted_lost = (delta - 1).astype(np.int32)
        clean_rows = clean[group_of_row]
        n_clean = int(np.count_nonzero(clean_rows))
        if n_clean:
            some_lost = int(np.count_nonzero(clean_rows & (delta > 1)))
            self.stats["ok"] += n_clean - some_lost
            self.stats["some_lost"] += some_lost
            self.stats["lost_frames"] += int(sorted_lost[clean_rows].sum())
        last_rows = np.append(starts[1:], n) - 1
        last_counter = sorted_counters[last_rows].tolist()
        last_time = timestamps[order[last_rows]].tolist()
        bounds = np.append(starts, n).tolist()
        for g, st in enumerate(states):
            if st is None:                  # an identifier that is not in the catalogue
                known[g] = False
            if clean[g] and st is not None:
                self._accept(st, last_counter[g], last_time[g], runs=int(sizes[g]))
                continue
            begin, end = bounds[g], bounds[g + 1]
            rows = order[begin:end]
            if not known[g] or st is None:
                sorted_status[begin:end] = _ERROR
                sorted_lost[begin:end] = 0
                self.stats["unknown_id"] += end - begin
                continue
            group_status, group_lost = self._check_group(st, counters[rows], crc_ok[rows], timestamps[rows])
            sorted_status[begin:end] = group_status
            sorted_lost[begin:end] = group_lost
        statuses[order] = sorted_status
        lost[order] = sorted_lost
        return statuses, lost

    def _check_group(
        self, st: _IdState, counters: np.ndarray, crc_ok: np.ndarray, timestamps: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray]:
        """Frames of one identifier: runs in sequence at once, the others one by one. Whether a frame
        follows its predecessor in the group is computed once for all (only a run's first frame is
        compared with the receiver's reference), so the work is O(n log n) however irregular the
        frames are (a shuffled stream)."""
        size = counters.shape[0]
        statuses = np.empty(size, dtype=np.int8)
        lost = np.zeros(size, dtype=np.int32)
        stats = self.stats
        step = (counters[1:] - counters[:-1]) % st.modulus
        follows = crc_ok[1:] & (step >= 1) & (step <= st.max_delta)      # row k + 1 follows row k
        breaks = np.flatnonzero(~follows) + 1                             # rows that do not
        pos = 0
        while pos < size:
            if st.reference >= 0 and crc_ok[pos]:
                first = int((counters[pos] - st.reference) % st.modulus)
                if 1 <= first <= st.max_delta:
                    after = int(np.searchsorted(breaks, pos, side="right"))
                    end = int(breaks[after]) if after < breaks.size else size
                    run = end - pos
                    run_delta = np.concatenate(([first], step[pos:end - 1]))
                    jumped = run_delta > 1
                    statuses[pos:end] = np.where(jumped, E2EStatus.OK_SOME_LOST, E2EStatus.OK)
                    lost[pos:end] = run_delta - 1
                    some_lost = int(np.count_nonzero(jumped))
                    stats["some_lost"] += some_lost
                    stats["ok"] += run - some_lost
                    stats["lost_frames"] += int(run_delta.sum()) - run
                    self._accept(st, int(counters[end - 1]), float(timestamps[end - 1]), runs=run)
                    pos = end
                    if pos >= size:
                        break
            status, n_lost = self._check_one(st, int(counters[pos]), bool(crc_ok[pos]), float(timestamps[pos]))
            statuses[pos] = status
            lost[pos] = n_lost
            pos += 1
        return statuses, lost

    # -- timeouts ----------------------------------------------------------------------------

    def poll(self, now: float) -> list[tuple[int, E2EStatus]]:
        """Identifiers seen before whose last accepted frame is older than their timeout at
        ``now`` (same clock as the frame timestamps, s); each outage is reported once."""
        reports: list[tuple[int, E2EStatus]] = []
        for arbitration_id, st in self._states.items():
            if st.timed_out or st.state is E2EState.INIT and st.last_accepted == -math.inf:
                continue
            if now - st.last_accepted > st.timeout_s:
                st.timed_out = True
                self._invalidate(st)
                self.stats["no_new_data"] += 1
                reports.append((arbitration_id, E2EStatus.NO_NEW_DATA))
        return reports
