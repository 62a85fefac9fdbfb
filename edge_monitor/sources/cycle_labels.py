"""Cycle and segment labels for sources whose controller does not send ours (docs/CONNECTING.md).

A labeller turns time-ordered input into change points ``(tick, cycle, segment)``: from that tick on,
samples belong to that cycle and segment (segment codes as docs/PROTOCOL.md: speed level k is k + 1, 0 a
transition, 200 production). ``update`` returns the *horizon*: labels of samples before it are final.

* :class:`ControllerLabels` — the controller's own cycle and segment signals, mapped from its frames or
  table, taken only where they are plausible (as our status frames: a row number is no cycle counter).
* :class:`TriggerLabels` — a trigger signal (a program number, a digital output): a cycle starts where it
  takes the mapped value and lasts while it keeps it; the rest is production.
* :class:`MotionLabels` — the motion itself: the designed constant-speed levels, in order, found on one
  reference joint with the plateau detector of :mod:`~edge_monitor.features.segmentation` at the designed
  speeds. A cycle starts at a plateau of the first level (either direction, when the open cycle has gone
  past it or already has that direction); later levels count only in increasing order and once per
  direction, so the production motion, which comes after the last level, is ignored even where it holds
  a level's speed; after the last level everything is production until the first level comes again.
  Labels are final only once a plateau ends, so the horizon is the start of the level run in progress.
"""

from __future__ import annotations

from dataclasses import replace
from typing import Any, Protocol

import numpy as np
from numpy.typing import NDArray

from edge_monitor.features.segmentation import PlateauConfig, PlateauDetector, PlateauStat
from edge_monitor.sources.cycle_numbering import CycleNumbering
from protocol.frames import SEGMENT_NONE, SEGMENT_PRODUCTION, STATUS_TICK_MODULUS

Marks = dict[str, tuple[NDArray[np.int64], NDArray[np.float64]]]
#: Largest cycle and segment numbers a controller's marks may carry (a cycle counter of 31 bits; our
#: segment codes 0 … 255); a larger, negative or fractional mark is no cycle or segment number.
MAX_CYCLE_MARK, MAX_SEGMENT_MARK = 2**31 - 1, 255


class CycleLabeller(Protocol):
    changes: list[tuple[int, int, int]]
    method: str

    def update(self, tick: NDArray[np.int64], speed: NDArray[np.float64], marks: Marks, latest: int) -> int: ...
    def flush(self) -> None: ...
    def counters(self) -> dict[str, int]: ...
    def state_dict(self) -> dict[str, Any]: ...
    def load_state(self, state: dict[str, Any]) -> None: ...


class _Numbered:
    """Cycle numbering shared by the labellers (persisted: a restarted agent keeps counting)."""

    def __init__(self) -> None:
        self.changes: list[tuple[int, int, int]] = []
        self.cycle = -1
        self.found = 0

    def _start(self, tick: int, segment: int) -> None:
        self.cycle += 1
        self.found += 1
        self.changes.append((tick, self.cycle, segment))

    def flush(self) -> None:
        pass

    def counters(self) -> dict[str, int]:
        return {"cycles_found": self.found}

    def state_dict(self) -> dict[str, Any]:
        return {"cycle": self.cycle}

    def load_state(self, state: dict[str, Any]) -> None:
        if isinstance(state.get("cycle"), int):
            self.cycle = int(state["cycle"])


class ControllerLabels:
    """The controller's cycle and segment signals (both mapped; values as our ControllerStatus), taken as
    our own status frames are (:mod:`~edge_monitor.sources.cycle_numbering`): a cycle mark changes the
    cycle in force only where it is plausible progress or a confirmed controller restart, and only after
    ``MIN_CYCLE_S`` without a mark that jumped or was no number, so a signal that is no cycle counter (a row
    number, a speed) finds no cycles but counts ``cycle_jumps`` (dropping stale marks from before a gap for the
    one after it is no such jump: the resumption is confirmed as on our frames). A mark that is no cycle or
    segment number (not an integer, negative, beyond :data:`MAX_CYCLE_MARK` or :data:`MAX_SEGMENT_MARK`) is
    dropped and counted (``bad_marks``)."""

    method = "controller marks"

    def __init__(self, rate_hz: float = 500.0) -> None:
        self.numbering = CycleNumbering(rate_hz)
        self.changes: list[tuple[int, int, int]] = []
        self.found = 0
        self.bad_marks = 0
        self._every = max(self.numbering.confirm_ticks // 4, 1)   # dense marks: one per this many ticks
        self._last: tuple[float, float, int] = (np.nan, np.nan, -1)   # cycle, segment, tick of the last mark
        self._in_force: tuple[int, int] | None = None
        self._waiting: list[int] = []      # ticks of marks the numbering has not taken yet
        self._noisy = -(1 << 62)           # tick of the last mark that jumped or was no number
        self.held = 0                      # new cycle numbers not taken: too soon after such a mark
        self._noisy_jump = -(1 << 62)      # tick of the last mark the numbering called a jump

    def update(self, tick: NDArray[np.int64], speed: NDArray[np.float64], marks: Marks, latest: int) -> int:
        if "cycle" in marks and "segment" in marks:
            for t, cycle, segment, noisy in self._events(marks).tolist():
                self._take(int(t), int(cycle), int(segment), int(noisy))
        return self._waiting[0] if self._waiting else latest + 1

    def _valid(self, values: NDArray[np.float64], limit: int) -> NDArray[np.bool_]:
        with np.errstate(invalid="ignore"):
            ok = np.isfinite(values) & (values >= 0) & (values <= limit) & (values == np.round(values))
        self.bad_marks += int((~ok).sum())
        return ok

    def _events(self, marks: Marks) -> NDArray[np.int64]:
        """(tick, cycle, segment, tick of the last bad mark) rows in time order: the marks merged and carried
        forward, one per tick, repeats thinned to one per ``_every`` ticks (the numbering needs them only to
        see the stream go on)."""
        (t_c, cycles), (t_s, segments) = marks["cycle"], marks["segment"]
        ok_c, ok_s = self._valid(cycles, MAX_CYCLE_MARK), self._valid(segments, MAX_SEGMENT_MARK)
        bad = np.sort(np.concatenate([t_c[~ok_c], t_s[~ok_s]]))
        tick = np.concatenate([t_c[ok_c], t_s[ok_s]])
        cycle = np.concatenate([cycles[ok_c], np.full(int(ok_s.sum()), np.nan)])
        segment = np.concatenate([np.full(int(ok_c.sum()), np.nan), segments[ok_s]])
        order = np.argsort(tick, kind="stable")
        tick, cycle, segment = tick[order], cycle[order], segment[order]
        cycle, segment = (_carried(v, first) for v, first in zip((cycle, segment), self._last[:2]))
        if tick.size:
            self._last = (float(cycle[-1]), float(segment[-1]), int(tick[-1]))
        last_of_tick = np.append(tick[1:] != tick[:-1], True) & np.isfinite(cycle) & np.isfinite(segment)
        tick, cycle, segment = tick[last_of_tick], cycle[last_of_tick], segment[last_of_tick]
        bucket = tick // self._every
        new = np.ones(tick.size, dtype=bool)
        new[1:] = (cycle[1:] != cycle[:-1]) | (segment[1:] != segment[:-1]) | (bucket[1:] != bucket[:-1])
        tick, at = tick[new], np.searchsorted(bad, tick[new], side="right") - 1
        noisy = np.where(at >= 0, bad[np.maximum(at, 0)] if bad.size else 0, self._noisy)
        if bad.size:
            self._noisy = max(self._noisy, int(bad[-1]))
        return np.stack([tick, cycle[new], segment[new], noisy], axis=1).astype(np.int64)

    def _take(self, tick: int, cycle: int, segment: int, noisy: int) -> None:
        quiet = tick - max(noisy, self._noisy_jump) >= self.numbering.min_cycle_ticks
        if cycle != self.numbering.cycle_raw and not quiet:
            self.held += 1
            self._waiting = []
            return
        self._waiting.append(tick)
        jumps = self.numbering.jumps
        taken = self.numbering.update(cycle, segment, tick % STATUS_TICK_MODULUS, {})
        if self.numbering.jumps != jumps and not self.numbering.unconfirmed:
            self._noisy_jump = tick       # not when stale frames before a gap were dropped for this one
        if taken is None:
            keep = self.numbering.unconfirmed
            self._waiting = self._waiting[len(self._waiting) - keep:] if keep else []
            return
        start = self._waiting[-1 - self.numbering.taken_back]
        self._waiting = []
        if self._in_force is None or taken != self._in_force[0]:
            self.found += 1
        elif segment == self._in_force[1]:
            return
        self._in_force = (taken, segment)
        self.changes.append((start, taken, segment))

    @property
    def cycle(self) -> int:
        return -1 if self.numbering.cycle is None else self.numbering.cycle

    def flush(self) -> None:
        pass

    def counters(self) -> dict[str, int]:
        return {"cycles_found": self.found, "cycle_jumps": self.numbering.jumps + self.held,
                "controller_restarts": self.numbering.restarts, "bad_marks": self.bad_marks}

    def state_dict(self) -> dict[str, Any]:
        return self.numbering.state_dict()

    def load_state(self, state: dict[str, Any]) -> None:
        cycle, raw = state.get("cycle"), state.get("cycle_raw")
        if isinstance(cycle, int) and isinstance(raw, int):
            self.numbering.load_state({"cycle": cycle, "cycle_raw": raw})


def _carried(values: NDArray[np.float64], before: float) -> NDArray[np.float64]:
    """``values`` with each NaN replaced by the last number before it (``before`` at the start)."""
    known = np.isfinite(values)
    at = np.maximum.accumulate(np.where(known, np.arange(values.size), -1))
    return np.where(at >= 0, values[np.maximum(at, 0)], before)


class TriggerLabels(_Numbered):
    """A cycle while the trigger signal equals ``value`` (see the module docstring)."""

    method = "trigger signal"

    def __init__(self, value: float) -> None:
        super().__init__()
        self.value = value
        self._active: bool | None = None

    def update(self, tick: NDArray[np.int64], speed: NDArray[np.float64], marks: Marks, latest: int) -> int:
        if "trigger" in marks:
            ticks, values = marks["trigger"]
            for t, v in zip(ticks.tolist(), values.tolist()):
                active = bool(v == self.value)
                if active and self._active is False:
                    self._start(int(t), SEGMENT_NONE)
                elif not active and self._active and self.cycle >= 0:
                    self.changes.append((int(t), self.cycle, SEGMENT_PRODUCTION))
                self._active = active
        return latest + 1


class MotionLabels(_Numbered):
    """The designed levels in order on the reference joint (see the module docstring)."""

    method = "motion (designed speed levels)"

    def __init__(self, speeds: tuple[float, ...], rate_hz: float, plateau: PlateauConfig) -> None:
        super().__init__()
        self.detector = PlateauDetector(replace(plateau, speeds=tuple(speeds)), rate_hz)
        self.levels = len(speeds)
        self._level = -1
        self._directions: set[int] = set()
        self._done = False
        self.ignored = 0
        self._last_tick = -1

    def update(self, tick: NDArray[np.int64], speed: NDArray[np.float64], marks: Marks, latest: int) -> int:
        if tick.size:
            for plateau in self.detector.update(tick, speed, np.zeros_like(speed)):
                self._plateau(plateau)
            self._last_tick = int(tick[-1])
        start = self.detector.open_run_start
        return min(latest + 1, start) if start is not None else latest + 1

    def flush(self) -> None:
        for plateau in self.detector.flush():
            self._plateau(plateau)

    def _plateau(self, p: PlateauStat) -> None:
        level, direction = p.level, p.direction
        if level == 0 and (self.cycle < 0 or self._level != 0 or direction in self._directions):
            self._start(p.tick_start, 1)
            self._level, self._directions, self._done = 0, {direction}, False
        elif self.cycle >= 0 and not self._done and (
                level > self._level or (level == self._level and direction not in self._directions)):
            if level != self._level:
                self._level, self._directions = level, set()
            self._directions.add(direction)
            self.changes.append((p.tick_start, self.cycle, level + 1))
        else:
            self.ignored += 1
            return
        self._done = self._level == self.levels - 1 and len(self._directions) == 2
        self.changes.append((p.tick_end + 1, self.cycle, SEGMENT_PRODUCTION if self._done else SEGMENT_NONE))

    def counters(self) -> dict[str, int]:
        return {"cycles_found": self.found, "plateaus_ignored": self.ignored}
