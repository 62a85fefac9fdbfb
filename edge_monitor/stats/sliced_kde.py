"""A streaming KDE whose samples are moved, at the end of the window, by an amount known only then.

Some corrections of a sample depend on a per-cycle quantity that is known only when the cycle is over,
scaled by a per-sample coefficient known at once: the friction load term moves a torque sample by
``ε·d`` with ``d = ±s(|v|)`` from its speed and ``ε`` the change of the cycle's load torque, measured
at the plateaus (docs/KL_DETECTOR.md, "Load compensation"). Keeping the samples until then would need
memory O(cycle). Instead the samples are binned on a 2-D grid: linearly in the value ``y`` (as
:class:`~edge_monitor.stats.kde_stream.StreamingKDE` does) and linearly in the coefficient ``d`` over
``K`` equally spaced anchors ``d_k`` (a sample with ``d`` between two anchors gives each a share of its
mass). :meth:`SlicedKDE.collapse` then moves the slice of anchor ``k`` by ``−ε·d_k`` and re-bins all
slices onto one grid. A sample whose ``d`` is an anchor lands exactly where ``y − ε·d`` would; any
other is spread over ``|ε|·Δd`` (Δd the anchor spacing) around it, with its mean exact. The running
moments are those of the exact values ``y − ε·d`` (mean and variance of ``(y, d)`` kept), so the
bandwidth is the one of the corrected window. Memory O(K·grid), independent of the window's length.

Units: ``y`` and the grid in the unit of the binned quantity; ``d`` in that unit per unit of ``ε``.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from edge_monitor.stats.kde_stream import (
    MAX_GRID,
    ROUNDOFF_SPREAD,
    GridError,
    StreamingKDE,
    normal_reference_bandwidth,
)

#: Most anchors a sliced KDE may have (memory is anchors × grid).
MAX_ANCHORS = 64


class SlicedKDE:
    """Samples ``y`` with coefficients ``d`` on ``linspace(lo, hi, n_grid)`` × ``linspace(-d_max, d_max,
    n_anchors)`` (see the module docstring). Coefficients beyond ±``d_max`` are clipped to the end
    anchors and counted in ``n_clipped``."""

    def __init__(self, lo: float, hi: float, n_grid: int, d_max: float, n_anchors: int = 9) -> None:
        if not (math.isfinite(lo) and math.isfinite(hi) and hi > lo) or not 8 <= int(n_grid) <= MAX_GRID:
            raise GridError(f"SlicedKDE: need finite lo < hi and 8 … {MAX_GRID} points, got {lo}, {hi}, {n_grid}")
        if not (math.isfinite(d_max) and d_max > 0) or not 2 <= int(n_anchors) <= MAX_ANCHORS:
            raise GridError(f"SlicedKDE: need d_max > 0 and 2 … {MAX_ANCHORS} anchors, got {d_max}, {n_anchors}")
        self.lo, self.hi, self.n_grid = float(lo), float(hi), int(n_grid)
        self.dx = (self.hi - self.lo) / (self.n_grid - 1)
        self.d_max, self.n_anchors = float(d_max), int(n_anchors)
        self.anchors = np.linspace(-self.d_max, self.d_max, self.n_anchors)
        self.dd = 2.0 * self.d_max / (self.n_anchors - 1)
        self.reset()

    def reset(self) -> None:
        """Forget all samples (a new window); the grids stay."""
        self.mass = np.zeros((self.n_anchors, self.n_grid))
        self.n_samples = 0
        self.mean = np.zeros(2)            # running mean of (y, d)
        self.m2 = np.zeros((2, 2))         # Σ (x − mean)(x − mean)ᵀ of x = (y, d)
        self.n_below = self.n_above = self.n_nonfinite = self.n_clipped = 0

    @property
    def grid(self) -> NDArray[np.float64]:
        return np.linspace(self.lo, self.hi, self.n_grid)

    def update(self, samples: ArrayLike, coefficients: ArrayLike) -> None:
        """Bin a block of samples ``y`` with their coefficients ``d`` (same shape). Non-finite pairs are
        counted in ``n_nonfinite`` and skipped; samples outside ``[lo, hi]`` are counted in
        ``n_below``/``n_above`` (and in the moments) but not binned."""
        y = np.asarray(samples, dtype=float).reshape(-1)
        d = np.asarray(coefficients, dtype=float).reshape(-1)
        if d.shape != y.shape:
            raise ValueError(f"SlicedKDE.update: {d.size} coefficients for {y.size} samples")
        finite = np.isfinite(y) & np.isfinite(d)
        if not finite.all():
            self.n_nonfinite += int(y.size - np.count_nonzero(finite))
            y, d = y[finite], d[finite]
        if y.size == 0:
            return
        self._update_moments(y, d)
        below, above = y < self.lo, y > self.hi
        if below.any() or above.any():
            self.n_below += int(np.count_nonzero(below))
            self.n_above += int(np.count_nonzero(above))
            inside = ~(below | above)
            y, d = y[inside], d[inside]
        clipped = np.abs(d) > self.d_max
        if clipped.any():
            self.n_clipped += int(np.count_nonzero(clipped))
            d = np.clip(d, -self.d_max, self.d_max)
        self._bin(y, d)

    def _bin(self, y: NDArray[np.float64], d: NDArray[np.float64]) -> None:
        """Bilinear binning over the span of grid points the block occupies (O(samples + K·span))."""
        if y.size == 0:
            return
        t = (y - self.lo) * (1.0 / self.dx)
        j = np.minimum(t.astype(np.int64), self.n_grid - 2)
        fy = t - j
        u = (d + self.d_max) * (1.0 / self.dd)
        k = np.minimum(u.astype(np.int64), self.n_anchors - 2)
        fd = u - k
        first = int(j.min())
        span = int(j.max()) - first + 2
        base = k * span + (j - first)                   # the (anchor, grid) cell below-left of each sample
        gy, gd = 1.0 - fy, 1.0 - fd
        cells = np.concatenate((base, base + 1, base + span, base + span + 1))
        weights = np.concatenate((gd * gy, gd * fy, fd * gy, fd * fy))
        local = np.bincount(cells, weights=weights, minlength=self.n_anchors * span)
        self.mass[:, first:first + span] += local.reshape(self.n_anchors, span)

    def _update_moments(self, y: NDArray[np.float64], d: NDArray[np.float64]) -> None:
        """Chan et al. parallel combination of (n, mean, M2) of the pairs (y, d)."""
        x = np.stack([y, d])
        nb = y.size
        mean_b = x.mean(axis=1)
        dev = x - mean_b[:, None]
        m2_b = dev @ dev.T
        total = self.n_samples + nb
        delta = mean_b - self.mean
        self.mean = self.mean + delta * nb / total
        self.m2 = self.m2 + m2_b + np.outer(delta, delta) * self.n_samples * nb / total
        self.n_samples = total

    def corrected_moments(self, eps: float) -> tuple[float, float]:
        """Mean and M2 (Σ of squared deviations) of the corrected values ``y − eps·d``."""
        mean = float(self.mean[0] - eps * self.mean[1])
        m2 = float(self.m2[0, 0] - 2.0 * eps * self.m2[0, 1] + eps * eps * self.m2[1, 1])
        return mean, max(m2, 0.0)

    def bandwidth(self, eps: float) -> float:
        """Normal-reference bandwidth of the corrected values (0.0 with < 2 samples or no spread)."""
        if self.n_samples < 2:
            return 0.0
        mean, m2 = self.corrected_moments(eps)
        std = math.sqrt(m2 / (self.n_samples - 1))
        return normal_reference_bandwidth(self.n_samples, std) if std > ROUNDOFF_SPREAD * abs(mean) else 0.0

    def collapse(self, eps: float, lo: float, hi: float, n_grid: int, shift: float = 0.0) -> StreamingKDE:
        """The window as a :class:`StreamingKDE` on ``linspace(lo, hi, n_grid)`` of the values
        ``y − eps·d − shift``: slice k moved by ``−eps·d_k − shift`` and linearly re-binned; mass that
        lands outside the new grid is counted as outside, in samples (as :meth:`StreamingKDE.regrid`)."""
        out = StreamingKDE(lo, hi, n_grid)
        out.n_samples, out.sum_w, out.sum_w2 = self.n_samples, float(self.n_samples), float(self.n_samples)
        mean, out.m2 = self.corrected_moments(eps)
        out.mean = mean - float(shift)
        out.n_below, out.n_above, out.n_nonfinite = self.n_below, self.n_above, self.n_nonfinite
        out.mass_outside = float(self.n_below + self.n_above)
        grid = self.grid
        for k, anchor in enumerate(self.anchors):
            occupied = self.mass[k] > 0
            if not occupied.any():
                continue
            points, mass = grid[occupied] - float(shift) - eps * float(anchor), self.mass[k][occupied]
            below, above = points < lo, points > hi
            if below.any() or above.any():
                out.n_below += int(round(float(mass[below].sum())))
                out.n_above += int(round(float(mass[above].sum())))
                inside = ~(below | above)
                out.mass_outside += float(mass[~inside].sum())
                points, mass = points[inside], mass[inside]
            out._bin(points, mass)
        return out

    def occupied_range(self, eps: float = 0.0) -> tuple[float, float] | None:
        """``(lowest, highest)`` corrected position holding mass (slice k moved by ``−eps·d_k``)."""
        lows, highs = [], []
        for k, anchor in enumerate(self.anchors):
            nz = np.flatnonzero(self.mass[k] > 0)
            if nz.size:
                lows.append(self.lo + nz[0] * self.dx - eps * anchor)
                highs.append(self.lo + nz[-1] * self.dx - eps * anchor)
        return (float(min(lows)), float(max(highs))) if lows else None

    # -- persistence ------------------------------------------------------------------------
    def state_dict(self) -> dict[str, Any]:
        """JSON state: per anchor, the mass from its first to its last occupied bin."""
        slices = []
        for row in self.mass:
            nz = np.flatnonzero(row)
            first, last = (int(nz[0]), int(nz[-1]) + 1) if nz.size else (0, 0)
            slices.append({"offset": first, "mass": row[first:last].tolist()})
        return {"lo": self.lo, "hi": self.hi, "n_grid": self.n_grid, "d_max": self.d_max,
                "n_anchors": self.n_anchors, "slices": slices, "n_samples": self.n_samples,
                "mean": self.mean.tolist(), "m2": self.m2.tolist(), "n_below": self.n_below,
                "n_above": self.n_above, "n_nonfinite": self.n_nonfinite, "n_clipped": self.n_clipped}

    @classmethod
    def from_state(cls, state: dict[str, Any]) -> "SlicedKDE":
        """Restore; ``ValueError`` for a state no sliced KDE could have written."""
        kde = cls(float(state["lo"]), float(state["hi"]), int(state["n_grid"]), float(state["d_max"]),
                  int(state["n_anchors"]))
        slices = state["slices"]
        if not isinstance(slices, list) or len(slices) != kde.n_anchors:
            raise ValueError(f"SlicedKDE.from_state: expected {kde.n_anchors} slices")
        for k, part in enumerate(slices):
            mass = np.asarray(part["mass"], dtype=float).reshape(-1)
            offset = int(part["offset"])
            if offset < 0 or offset + mass.size > kde.n_grid or not np.all(np.isfinite(mass)) or np.any(mass < 0):
                raise ValueError(f"SlicedKDE.from_state: slice {k} does not fit the grid of {kde.n_grid} points")
            kde.mass[k, offset:offset + mass.size] = mass
        kde.mean = np.asarray(state["mean"], dtype=float).reshape(2)
        kde.m2 = np.asarray(state["m2"], dtype=float).reshape(2, 2)
        if not (np.all(np.isfinite(kde.mean)) and np.all(np.isfinite(kde.m2))):
            raise ValueError("SlicedKDE.from_state: non-finite moments")
        for key in ("n_samples", "n_below", "n_above", "n_nonfinite", "n_clipped"):
            value = int(state[key])
            if value < 0:
                raise ValueError(f"SlicedKDE.from_state: negative {key}")
            setattr(kde, key, value)
        return kde
