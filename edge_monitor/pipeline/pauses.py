"""Where a joint's sample stream pauses: the joint stood still (a stop, a shift change) and sent no samples.

A robot controller streams a joint's samples at its tick rate while the joint moves through its cycles; a
gap of at least :data:`PAUSE_S` in the controller ticks is a pause, during which the lubricant cooled. The
joint monitor cuts each block of samples at its pauses and tells the features before the samples after one
(:meth:`~edge_monitor.features.base.Feature.pause`). Units: ticks at the agent's ``rate_hz``, pauses in s.
"""

from __future__ import annotations

from typing import Any

import numpy as np
from numpy.typing import NDArray

#: The shortest gap in a joint's samples that is a pause [s].
PAUSE_S = 60.0


class PauseFinder:
    """``split(ticks) -> [(run, pause before it [s]), …]`` per block; remembers the last tick across blocks."""

    def __init__(self, rate_hz: float, last_tick: int | None = None) -> None:
        self.rate_hz = float(rate_hz)
        self.last_tick = last_tick

    def split(self, tick: NDArray[np.int64]) -> list[tuple[slice, float]]:
        """The block cut at its pauses (also one since the previous block): each run of samples with the
        pause before it [s] (0.0: none). A tick that goes back (a controller restart) is no pause."""
        if tick.size == 0:
            return []
        gap = int(PAUSE_S * self.rate_hz)
        steps = np.diff(tick, prepend=tick[0] if self.last_tick is None else self.last_tick)
        self.last_tick = int(tick[-1])
        bounds = [0, *(int(i) for i in np.flatnonzero(steps >= gap) if i > 0), int(tick.size)]
        pauses = [float(steps[i]) / self.rate_hz if steps[i] >= gap else 0.0 for i in bounds[:-1]]
        return [(slice(a, b), p) for a, b, p in zip(bounds[:-1], bounds[1:], pauses)]

    def state_dict(self) -> dict[str, Any]:
        return {"last_tick": self.last_tick}

    @classmethod
    def from_state(cls, rate_hz: float, state: Any) -> "PauseFinder":
        """From :meth:`state_dict`; anything unusable: no last tick (the next block starts afresh)."""
        last = state.get("last_tick") if isinstance(state, dict) else None
        return cls(rate_hz, last if isinstance(last, int) and not isinstance(last, bool) else None)
