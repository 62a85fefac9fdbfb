"""Cycle and segment labels for sources whose controller does not send ours (docs/CONNECTING.md).

A labeller turns time-ordered input into change points ``(tick, cycle, segment)``: from that tick on,
samples belong to that cycle and segment (segment codes as docs/PROTOCOL.md: speed level k is k + 1, 0 a
transition, 200 production). ``update`` returns the *horizon*: labels of samples before it are final.

* :class:`ControllerLabels` — the controller's own cycle and segment signals, mapped from its frames.
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
from protocol.frames import SEGMENT_NONE, SEGMENT_PRODUCTION

Marks = dict[str, tuple[NDArray[np.int64], NDArray[np.float64]]]


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


class ControllerLabels(_Numbered):
    """The controller's cycle and segment signals (both mapped; values as our ControllerStatus)."""

    method = "controller marks"

    def __init__(self) -> None:
        super().__init__()
        self._last: tuple[int, int] | None = None

    def update(self, tick: NDArray[np.int64], speed: NDArray[np.float64], marks: Marks, latest: int) -> int:
        if "cycle" in marks and "segment" in marks:
            t_c, cycles = marks["cycle"]
            t_s, segments = marks["segment"]
            order = np.argsort(np.concatenate([t_c, t_s]), kind="stable")
            for k in order.tolist():                 # a few marks per block: Python is fine
                if k < t_c.size:
                    self._set(int(t_c[k]), int(cycles[k]), None)
                else:
                    self._set(int(t_s[k - t_c.size]), None, int(segments[k - t_c.size]))
        return latest + 1

    def _set(self, tick: int, cycle: int | None, segment: int | None) -> None:
        last_cycle, last_segment = self._last if self._last is not None else (None, SEGMENT_NONE)
        cycle = last_cycle if cycle is None else cycle
        segment = last_segment if segment is None else segment
        if cycle is None or (cycle, segment) == self._last:
            return
        if cycle != last_cycle:
            self.found += 1
        self.cycle = cycle
        self._last = (cycle, segment)
        self.changes.append((tick, cycle, segment))


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
