"""The cycle in force, from the controller's status frames: unwrapped, restart-aware, and not fooled
by a reordered, replayed or corrupted stream.

A status frame carries the controller's 16-bit cycle number, its segment and its 24-bit tick. Taken
at face value, a stream whose status frames come out of order (shuffled log lines), whose cycle
number rises every frame, or whose tick runs backward turns each frame into a new cycle: thousands of
"cycles" from a six-cycle recording, and the per-cycle work with them. So a status frame is taken
(changes the cycle in force and its segment) only when it is plausible:

* it **continues** the last frame taken (tick 0 … ``confirm_ticks`` ahead; status frames come every
  10 ticks): the same cycle, or the next one entered at its start (segment 0 or 1) once the cycle
  has lasted ``min_cycle_ticks`` (when its start was seen);
* or it is a **discontinuity** (tick backward or far ahead, a cycle number out of step) that the
  next ``CONFIRMATIONS`` status frames confirm by continuing it: a controller restart (tick backward, or a cycle
  number not 0 … ``MAX_CYCLE_STEP`` ahead; numbering then goes on from the last cycle + 1, so
  published cycle numbers stay unique and increasing), or a resumption after a gap (lost frames, a
  silent bus) that moved k cycles on, believed when the tick advanced by at least
  (k − 1) × ``min_cycle_ticks``. Stray frames of the past or the future cannot confirm themselves.

Anything else is a jump: counted (``cycle_jumps``), and the frame does not change the cycle in force
or its segment. The work per status frame is constant. A confirmed discontinuity is known
``CONFIRMATIONS`` status frames (≈ 40 ms) late; the ingest labels the rows from its first frame on
where they are in the same block (``taken_back``).
"""

from __future__ import annotations

from dataclasses import dataclass

from protocol.frames import CYCLE_MODULUS, STATUS_TICK_MODULUS

#: Largest forward jump of the cycle counter taken as progress; larger or backward: controller restart.
MAX_CYCLE_STEP = 1000
#: Shortest test cycle believed [s] (real ones last tens of seconds).
MIN_CYCLE_S = 1.0
#: A frame continues another when its tick is at most this far ahead [s] (status frames come every 20 ms).
CONFIRM_S = 0.5
#: Status frames that must continue a discontinuity before it is believed.
CONFIRMATIONS = 2


def tick_step(previous_raw: int, raw: int) -> int | None:
    """Forward step of the 24-bit controller tick from ``previous_raw`` to ``raw``, or None when it
    went backward (more than half the counter's range)."""
    step = (raw - previous_raw) % STATUS_TICK_MODULUS
    return step if step < STATUS_TICK_MODULUS // 2 else None


@dataclass(frozen=True)
class _Frame:
    raw: int
    segment: int
    tick: int


class CycleNumbering:
    """Status frames in stream order → the unwrapped cycle in force (see the module docstring)."""

    def __init__(self, rate_hz: float = 500.0) -> None:
        self.min_cycle_ticks = max(int(rate_hz * MIN_CYCLE_S), 1)
        self.confirm_ticks = max(int(rate_hz * CONFIRM_S), 1)
        self.cycle: int | None = None          # unwrapped cycle in force
        self.cycle_raw: int | None = None
        self.anchored = False                  # a status frame was taken by this instance
        self.jumps = 0                         # status frames not taken (implausible cycle or tick)
        self.restarts = 0                      # controller restarts taken
        self.restarted = False                 # the last frame taken was a confirmed restart
        self.taken_back = 0                    # earlier frames taken with the last one (a confirmed discontinuity)
        self._tick: int | None = None          # tick of the last frame taken
        self._cycle_start: int | None = None   # tick where the cycle in force began (None: not seen)
        self._pending: list[_Frame] = []       # a discontinuity and the frames confirming it so far

    def update(self, raw: int, segment: int, tick: int, first_seen: dict[int, bool]) -> int | None:
        """The cycle in force after this status frame, or None when the frame is not taken (a jump,
        or a discontinuity waiting for its confirmation). ``first_seen[cycle]`` is set for a cycle
        entered here: whether its start was seen."""
        self.restarted, self.taken_back = False, 0
        frame = _Frame(raw, segment, tick)
        if self.cycle is None or self.cycle_raw is None:     # first status frame, no restored state
            first_seen[raw] = segment <= 1                  # its start seen: segment 0 or 1
            return self._take(frame, raw, started=segment <= 1)
        if self._pending:
            if self._continues(self._pending[-1], frame):
                self._pending.append(frame)
                if len(self._pending) <= CONFIRMATIONS:
                    return None
                frames, self._pending = self._pending, []
                return self._discontinuity(frames, first_seen)
            self.jumps += len(self._pending)                 # stray frames, not a discontinuity
            self._pending = []
        if self._tick is None:                               # restored state: nothing to compare the tick with
            return self._discontinuity([frame], first_seen)
        step_tick = tick_step(self._tick, tick)
        if step_tick is None or step_tick > self.confirm_ticks:
            self._pending = [frame]                          # a restart, a gap, or a stray frame
            return None
        if raw == self.cycle_raw:
            return self._take(frame, self.cycle)
        if (raw - self.cycle_raw) % CYCLE_MODULUS == 1 and segment <= 1 and self._lasted(tick):
            first_seen[self.cycle + 1] = True
            # it began after the last frame of the cycle before: lost status frames at its start must not
            # make it look shorter than it was
            return self._take(frame, self.cycle + 1, started=True, start_tick=self._tick)
        self.jumps += 1                                      # out of step within a continuous stream
        return None

    @property
    def unconfirmed(self) -> int:
        """Frames not taken yet because they may start a discontinuity (taken back once confirmed)."""
        return len(self._pending)

    def _lasted(self, tick: int) -> bool:
        """The cycle in force lasted ``min_cycle_ticks`` by ``tick`` (or its start was not seen), counted from
        the last frame of the cycle before where it was entered by progress."""
        start = self._cycle_start
        return start is None or (tick_step(start, tick) or 0) >= self.min_cycle_ticks

    def _continues(self, earlier: _Frame, frame: _Frame) -> bool:
        step = tick_step(earlier.tick, frame.tick)
        return frame.raw == earlier.raw and step is not None and step <= self.confirm_ticks

    def _discontinuity(self, frames: list[_Frame], first_seen: dict[int, bool]) -> int | None:
        """Take a confirmed discontinuity (its first frame, then those that confirmed it; one frame
        after a restore): a controller restart, or progress after a gap if the tick advanced enough
        for the cycles skipped."""
        assert self.cycle is not None and self.cycle_raw is not None
        first = frames[0]
        step = (first.raw - self.cycle_raw) % CYCLE_MODULUS
        restored = self._tick is None
        step_tick = None if self._tick is None else tick_step(self._tick, first.tick)
        if (not restored and step_tick is None) or step > MAX_CYCLE_STEP:   # tick backward, number out of range
            first_seen[self.cycle + 1] = self.anchored or first.segment <= 1
            self.restarts += 1
            self.restarted = True
            cycle = self._take(first, self.cycle + 1, started=first_seen[self.cycle + 1])
        elif step == 0:                                      # the same cycle, after a gap or a restore
            if restored:
                first_seen[self.cycle] = False               # joined mid-way
            cycle = self._take(first, self.cycle)
        elif step_tick is not None and step_tick < (step - 1) * self.min_cycle_ticks:
            self.jumps += len(frames)                        # more cycles than the time allows
            return None
        else:
            first_seen[self.cycle + step] = self.anchored or first.segment <= 1
            cycle = self._take(first, self.cycle + step, started=first_seen[self.cycle + step])
        for frame in frames[1:]:
            cycle = self._take(frame, cycle)
        self.taken_back = len(frames) - 1
        return cycle

    def _take(self, frame: _Frame, cycle: int, started: bool | None = None, start_tick: int | None = None) -> int:
        """Make ``frame`` the last one taken; ``started``: a new cycle begins (its start tick known or not:
        ``start_tick``, else the frame's)."""
        if started is not None:
            self._cycle_start = (frame.tick if start_tick is None else start_tick) if started else None
        self.cycle, self.cycle_raw, self._tick = cycle, frame.raw, frame.tick
        self.anchored = True
        return cycle

    # ------------------------------------------------------------------ persistence
    def state_dict(self) -> dict[str, int | None]:
        return {"cycle": self.cycle, "cycle_raw": self.cycle_raw}

    def load_state(self, state: dict) -> None:
        """A restarted agent keeps its numbering; where the controller is now is not known."""
        self.cycle, self.cycle_raw = state.get("cycle"), state.get("cycle_raw")
        self.anchored, self._tick, self._cycle_start, self._pending = False, None, None, []
