"""One channel of the distribution-domain monitor (raw torque, or weighted torque): its streaming KDE
on a capture grid, the working grid fixed from the first valid cycle, and the nominal density learned
from the first cycles (docs/ALGORITHMS.md §4; the grid choice, centring and load compensation are
described in :mod:`edge_monitor.features.kl_monitor`). With load compensation the capture is a
:class:`~edge_monitor.stats.sliced_kde.SlicedKDE`: each sample carries its load coefficient and the
window is moved to the reference load when the cycle's load is known, at its end. Units: torque
dimensionless, KL dimensionless.
"""

from __future__ import annotations

import logging
from typing import Any

import numpy as np
from numpy.typing import NDArray

from edge_monitor.stats.kde_stream import StreamingKDE, choose_grid, symmetric_kl
from edge_monitor.stats.sliced_kde import SlicedKDE
from protocol.frames import TORQUE_SCALE

log = logging.getLogger(__name__)

#: Wire range of torque (docs/PROTOCOL.md: 16-bit signed): ±1.6384.
TORQUE_WIRE_LIMIT = TORQUE_SCALE * (1 << 15)
#: Points of the provisional grid used until the working grid is fixed.
PROVISIONAL_GRID = 16384
#: Grid margin: fraction of the occupied range, and minimum in bandwidths of the first cycle.
GRID_MARGIN = 0.25
GRID_MIN_MARGIN_BANDWIDTHS = 4.0
#: Anchors of the load coefficient of a compensated capture (:class:`SlicedKDE`): a sample between
#: two anchors is spread over |ε|·Δd, Δd = 2·d_max/(anchors − 1) (docs/KL_DETECTOR.md).
LOAD_ANCHORS = 9


class KLChannel:
    """One quantity (raw torque, or weighted torque): its KDE, grid and nominal model.

    Without centring and without compensation, ``kde`` bins on the provisional grid until the
    working grid is fixed and on the working grid afterwards (:meth:`window_kde` is ``kde`` itself).
    With centring, ``kde`` always bins on the fine provisional grid over the wire range and
    :meth:`window_kde` moves the cycle's mass by −(cycle mean) onto the working grid ``[lo, hi]``
    (linear interpolation). With load compensation (``d_max`` > 0: the largest |load coefficient| of a
    sample) ``kde`` is a :class:`SlicedKDE` on the provisional grid and :meth:`window_kde` moves each
    sample by −ε·d (ε the cycle's load change from the reference) before centring."""

    def __init__(self, n_grid: int, center: bool, d_max: float = 0.0) -> None:
        self.n_grid = n_grid
        self.center = center
        self.d_max = float(d_max)
        self.kde: StreamingKDE | SlicedKDE = self._capture()
        self.grid_fixed = False
        self.lo = self.hi = None  # type: float | None   # working grid bounds once fixed
        self.learning: list[NDArray[np.float64]] = []   # densities of the learning cycles
        self.nominal: NDArray[np.float64] | None = None
        self.mu0 = self.sigma0 = None  # type: float | None

    @property
    def compensated(self) -> bool:
        return self.d_max > 0

    def _capture(self) -> StreamingKDE | SlicedKDE:
        if self.compensated:
            return SlicedKDE(-TORQUE_WIRE_LIMIT, TORQUE_WIRE_LIMIT, PROVISIONAL_GRID, self.d_max, LOAD_ANCHORS)
        return StreamingKDE(-TORQUE_WIRE_LIMIT, TORQUE_WIRE_LIMIT, PROVISIONAL_GRID)

    def update(self, values: NDArray[np.float64], coefficients: NDArray[np.float64] | None) -> None:
        """Bin a block of this channel's values (with their load coefficients when compensated)."""
        if isinstance(self.kde, SlicedKDE):
            assert coefficients is not None
            self.kde.update(values, coefficients)
        else:
            self.kde.update(values)

    @property
    def n_samples(self) -> int:
        return self.kde.n_samples

    @property
    def n_nonfinite(self) -> int:
        return self.kde.n_nonfinite

    def counts(self) -> dict[str, int]:
        """Samples of the open window below/above the capture grid and non-finite."""
        return {"below": self.kde.n_below, "above": self.kde.n_above, "nonfinite": self.kde.n_nonfinite}

    def shift(self, eps: float = 0.0) -> float:
        """Location removed from this window: the (load-corrected) cycle mean with centring, else 0."""
        if not self.center:
            return 0.0
        if isinstance(self.kde, SlicedKDE):
            return self.kde.corrected_moments(eps)[0]
        return self.kde.mean

    def has_spread(self, eps: float = 0.0) -> bool:
        """Whether the (corrected) window has a positive bandwidth."""
        return (self.kde.bandwidth(eps) if isinstance(self.kde, SlicedKDE) else self.kde.bandwidth) > 0

    def fix_grid(self, eps: float = 0.0) -> None:
        window = self.window_kde(eps, provisional=True)
        occupied = window.occupied_range()
        assert occupied is not None
        lo, hi = choose_grid(occupied[0], occupied[1], margin=GRID_MARGIN,
                             min_margin=max(GRID_MIN_MARGIN_BANDWIDTHS * window.bandwidth, 10 * TORQUE_SCALE),
                             bounds=(-TORQUE_WIRE_LIMIT, TORQUE_WIRE_LIMIT))
        self.lo, self.hi = lo, hi
        if not self.center and isinstance(self.kde, StreamingKDE):
            self.kde = self.kde.regrid(lo, hi, self.n_grid)
        self.grid_fixed = True
        log.info("KL grid fixed to [%.5f, %.5f] with %d points%s", lo, hi, self.n_grid,
                 " (centred)" if self.center else "")

    def window_kde(self, eps: float = 0.0, provisional: bool = False) -> StreamingKDE:
        """The window (load-corrected by ``eps``, centred) on the working grid once it is fixed, or on
        the provisional grid with ``provisional``."""
        lo, hi, n = (-TORQUE_WIRE_LIMIT, TORQUE_WIRE_LIMIT, PROVISIONAL_GRID) if provisional \
            else (self.lo, self.hi, self.n_grid)
        if isinstance(self.kde, SlicedKDE):
            return self.kde.collapse(eps, lo, hi, n, shift=self.shift(eps))  # type: ignore[arg-type]
        if not self.center:
            return self.kde
        return self.kde.regrid(lo, hi, n, shift=self.kde.mean)  # type: ignore[arg-type]

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
    def from_state(cls, n_grid: int, center: bool, state: dict[str, Any], d_max: float = 0.0) -> "KLChannel":
        ch = cls(n_grid, center, d_max)
        ch.kde = SlicedKDE.from_state(state["kde"]) if ch.compensated else StreamingKDE.from_state(state["kde"])
        ch.grid_fixed = bool(state["grid_fixed"])
        if ch.grid_fixed:     # states before centring existed: the working grid is the kde's grid
            ch.lo = float(state["lo"]) if state.get("lo") is not None else ch.kde.lo
            ch.hi = float(state["hi"]) if state.get("hi") is not None else ch.kde.hi
        ch.learning = [np.asarray(d, dtype=float) for d in state["learning"]]
        ch.nominal = None if state["nominal"] is None else np.asarray(state["nominal"], dtype=float)
        ch.mu0, ch.sigma0 = state["mu0"], state["sigma0"]
        return ch
