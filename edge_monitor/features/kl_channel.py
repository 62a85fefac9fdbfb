"""One channel of the distribution-domain monitor (raw torque, or weighted torque): its streaming KDE
on a capture grid, the working grid fixed from the first valid cycle, and the nominal density learned
from the first cycles (docs/ALGORITHMS.md §4; the grid choice and centring are described in
:mod:`edge_monitor.features.kl_monitor`). Units: torque dimensionless, KL dimensionless.
"""

from __future__ import annotations

import logging
from typing import Any

import numpy as np
from numpy.typing import NDArray

from edge_monitor.stats.kde_stream import StreamingKDE, choose_grid, symmetric_kl
from protocol.frames import TORQUE_SCALE

log = logging.getLogger(__name__)

#: Wire range of torque (docs/PROTOCOL.md: 16-bit signed): ±1.6384.
TORQUE_WIRE_LIMIT = TORQUE_SCALE * (1 << 15)
#: Points of the provisional grid used until the working grid is fixed.
PROVISIONAL_GRID = 16384
#: Grid margin: fraction of the occupied range, and minimum in bandwidths of the first cycle.
GRID_MARGIN = 0.25
GRID_MIN_MARGIN_BANDWIDTHS = 4.0


class KLChannel:
    """One quantity (raw torque or weighted torque): its KDE, grid and nominal model.

    Without centring, ``kde`` bins on the provisional grid until the working grid is fixed and on
    the working grid afterwards (:meth:`window_kde` is ``kde`` itself). With centring, ``kde`` always
    bins on the fine provisional grid over the wire range and :meth:`window_kde` moves the cycle's
    mass by −(cycle mean) onto the working grid ``[lo, hi]`` (linear interpolation)."""

    def __init__(self, n_grid: int, center: bool) -> None:
        self.n_grid = n_grid
        self.center = center
        self.kde = StreamingKDE(-TORQUE_WIRE_LIMIT, TORQUE_WIRE_LIMIT, PROVISIONAL_GRID)
        self.grid_fixed = False
        self.lo = self.hi = None  # type: float | None   # working grid bounds once fixed
        self.learning: list[NDArray[np.float64]] = []   # densities of the learning cycles
        self.nominal: NDArray[np.float64] | None = None
        self.mu0 = self.sigma0 = None  # type: float | None

    @property
    def shift(self) -> float:
        """Location removed from this window: the cycle mean with centring, else 0."""
        return self.kde.mean if self.center else 0.0

    def fix_grid(self) -> None:
        occupied = self.kde.occupied_range()
        assert occupied is not None
        lo, hi = choose_grid(occupied[0] - self.shift, occupied[1] - self.shift, margin=GRID_MARGIN,
                             min_margin=max(GRID_MIN_MARGIN_BANDWIDTHS * self.kde.bandwidth, 10 * TORQUE_SCALE),
                             bounds=(-TORQUE_WIRE_LIMIT, TORQUE_WIRE_LIMIT))
        self.lo, self.hi = lo, hi
        if not self.center:
            self.kde = self.kde.regrid(lo, hi, self.n_grid)
        self.grid_fixed = True
        log.info("KL grid fixed to [%.5f, %.5f] with %d points%s", lo, hi, self.n_grid,
                 " (centred)" if self.center else "")

    def window_kde(self) -> StreamingKDE:
        """The window on the working grid (grid fixed): centred copy, or ``kde`` itself."""
        if not self.center:
            return self.kde
        return self.kde.regrid(self.lo, self.hi, self.n_grid, shift=self.kde.mean)  # type: ignore[arg-type]

    @property
    def grid(self) -> NDArray[np.float64]:
        return np.linspace(self.lo, self.hi, self.n_grid)  # type: ignore[arg-type]

    @property
    def dx(self) -> float:
        return (self.hi - self.lo) / (self.n_grid - 1)  # type: ignore[operator]

    def finish_learning(self) -> None:
        stack = np.asarray(self.learning)
        k = stack.shape[0]
        self.nominal = stack.mean(axis=0)
        others = (stack.sum(axis=0)[None, :] - stack) / (k - 1)
        q = np.array([symmetric_kl(others[i], stack[i], self.dx) for i in range(k)])
        self.mu0, self.sigma0 = float(q.mean()), float(q.std(ddof=1))
        self.learning = []

    @property
    def threshold(self) -> float | None:
        return None if self.mu0 is None or self.sigma0 is None else self.mu0 + 3.0 * self.sigma0

    def new_window(self) -> None:
        self.kde.reset()

    def state_dict(self) -> dict[str, Any]:
        return {"kde": self.kde.state_dict(), "grid_fixed": self.grid_fixed, "lo": self.lo, "hi": self.hi,
                "learning": [d.tolist() for d in self.learning],
                "nominal": None if self.nominal is None else self.nominal.tolist(),
                "mu0": self.mu0, "sigma0": self.sigma0}

    @classmethod
    def from_state(cls, n_grid: int, center: bool, state: dict[str, Any]) -> "KLChannel":
        ch = cls(n_grid, center)
        ch.kde = StreamingKDE.from_state(state["kde"])
        ch.grid_fixed = bool(state["grid_fixed"])
        if ch.grid_fixed:     # states before centring existed: the working grid is the kde's grid
            ch.lo = float(state["lo"]) if state.get("lo") is not None else ch.kde.lo
            ch.hi = float(state["hi"]) if state.get("hi") is not None else ch.kde.hi
        ch.learning = [np.asarray(d, dtype=float) for d in state["learning"]]
        ch.nominal = None if state["nominal"] is None else np.asarray(state["nominal"], dtype=float)
        ch.mu0, ch.sigma0 = state["mu0"], state["sigma0"]
        return ch
