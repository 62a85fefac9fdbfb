"""Streaming kernel density estimate on a fixed grid and the symmetric KL distance (docs/ALGORITHMS.md §4).

Samples arrive in blocks; each block is linearly binned onto a fixed grid (``np.bincount``, no
Python loop per sample) and running moments are kept (Chan/Welford combination of blocks) for the
normal-reference bandwidth ``h = (4/(3n))^(1/5)·σ̂``. At the end of a window the density is the
binned mass convolved with a Gaussian kernel by FFT. Memory is O(grid), independent of the number of
samples. Samples outside the grid and non-finite samples are counted (``n_below``, ``n_above``,
``n_nonfinite``), never dropped silently.

Units: the grid is in the unit of the binned quantity (e.g. dimensionless joint torque); densities
are per unit of that quantity.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.signal import fftconvolve

#: Largest grid [points]: memory is O(grid); 65536 points is 0.5 MB.
MAX_GRID = 65536
#: Kernel truncation in bandwidths: the Gaussian mass beyond 5 h is 5.7e-7.
KERNEL_TRUNCATION = 5.0
#: Default density floor for the KL distance, relative to the larger of the two peaks. The floor
#: keeps the log finite where either density is (numerically) zero; with a relative floor the KL
#: value stays invariant to a rescaling of the quantity, like the continuous KL.
DEFAULT_RELATIVE_FLOOR = 1e-6


#: Relative spread below which data count as constant (a few hundred ulps of the mean).
ROUNDOFF_SPREAD = 1e-13


class KDEDataError(ValueError):
    """The window cannot give a density (too few samples, zero variance, no finite samples)."""


class GridError(ValueError):
    """An invalid grid specification (bounds or size)."""


def choose_grid(lo: float, hi: float, margin: float = 0.25, min_margin: float = 0.0,
                bounds: tuple[float, float] | None = None) -> tuple[float, float]:
    """Grid bounds covering ``[lo, hi]`` plus a margin on each side.

    The margin is ``max(margin·(hi − lo), min_margin)`` (same unit as the data); with ``bounds``
    the result is clipped to the physically possible range (e.g. the wire range of the quantity).
    Raises :class:`GridError` if the result is empty (e.g. ``lo == hi`` and no ``min_margin``).
    """
    if not (math.isfinite(lo) and math.isfinite(hi)) or hi < lo:
        raise GridError(f"choose_grid: need finite lo <= hi, got lo={lo}, hi={hi}")
    pad = max(margin * (hi - lo), min_margin)
    new_lo, new_hi = lo - pad, hi + pad
    if bounds is not None:
        new_lo, new_hi = max(new_lo, bounds[0]), min(new_hi, bounds[1])
    if not new_hi > new_lo:
        raise GridError(f"choose_grid: empty grid [{new_lo}, {new_hi}]; give a positive min_margin")
    return float(new_lo), float(new_hi)


def normal_reference_bandwidth(n_effective: float, std: float) -> float:
    """``h = (4/(3n))^(1/5)·σ̂`` (Silverman's normal reference rule, d = 1)."""
    return (4.0 / (3.0 * n_effective)) ** 0.2 * std


def gaussian_kernel(h: float, dx: float, max_half_width: int) -> NDArray[np.float64]:
    """Gaussian kernel sampled at the grid offsets ``j·dx``, truncated at ``KERNEL_TRUNCATION·h``
    (at most ``max_half_width`` bins) and normalised to unit discrete sum, so convolution conserves
    the binned mass even when ``h`` is small compared to ``dx``."""
    half = int(min(max(math.ceil(KERNEL_TRUNCATION * h / dx), 1), max_half_width))
    offsets = np.arange(-half, half + 1) * dx
    with np.errstate(under="ignore"):          # far tails underflow to 0: harmless
        kernel = np.exp(-0.5 * (offsets / h) ** 2)
    return kernel / kernel.sum()


def symmetric_kl(p0: ArrayLike, p: ArrayLike, dx: float, floor: float | None = None) -> float:
    """Symmetric Kullback–Leibler distance ``∫ (p0 − p)·log(p0/p) dy`` on a uniform grid (step ``dx``).

    Both densities are floored at ``ε`` inside the log only: ``log(max(p0, ε)/max(p, ε))``. As
    ``max(·, ε)`` is monotone, every term is ≥ 0, the result is ≥ 0 and 0 for equal densities.
    ``floor=None`` uses ``ε = DEFAULT_RELATIVE_FLOOR · max(max p0, max p)``. Two all-zero densities
    give 0.0. The integral is the Riemann sum on the grid.
    """
    a = np.asarray(p0, dtype=float)
    b = np.asarray(p, dtype=float)
    if a.shape != b.shape:
        raise ValueError(f"symmetric_kl: densities on different grids, shapes {a.shape} vs {b.shape}")
    if not (np.all(np.isfinite(a)) and np.all(np.isfinite(b))):
        raise ValueError("symmetric_kl: densities must be finite")
    peak = max(float(a.max(initial=0.0)), float(b.max(initial=0.0)))
    eps = DEFAULT_RELATIVE_FLOOR * peak if floor is None else float(floor)
    if peak <= 0.0:
        return 0.0
    if not eps > 0.0:
        raise ValueError(f"symmetric_kl: floor must be > 0, got {eps}")
    log_ratio = np.log(np.maximum(a, eps)) - np.log(np.maximum(b, eps))
    return float(np.sum((a - b) * log_ratio) * dx)


class StreamingKDE:
    """Gaussian KDE of a stream of scalar samples on the fixed grid ``linspace(lo, hi, n_grid)``.

    ``add`` accepts blocks with optional non-negative per-sample mass ``weights`` (default 1).
    The bandwidth uses the weighted running standard deviation (ddof = 1 for unit weights) and
    Kish's effective sample size ``(Σw)²/Σw²`` (= n for unit weights).
    """

    def __init__(self, lo: float, hi: float, n_grid: int = 512) -> None:
        if not (math.isfinite(lo) and math.isfinite(hi) and hi > lo):
            raise GridError(f"StreamingKDE: need finite lo < hi, got lo={lo}, hi={hi}")
        if int(n_grid) < 8:
            raise GridError(f"StreamingKDE: n_grid must be >= 8, got {n_grid}")
        self.lo, self.hi, self.n_grid = float(lo), float(hi), int(n_grid)
        self.dx = (self.hi - self.lo) / (self.n_grid - 1)
        self.reset()

    # -- accumulation -------------------------------------------------------------------------
    def reset(self) -> None:
        """Forget all samples (start a new window); the grid stays."""
        self.mass = np.zeros(self.n_grid)
        self.sum_w = 0.0       # Σw over all finite samples (in and outside the grid)
        self.sum_w2 = 0.0      # Σw²
        self.mean = 0.0
        self.m2 = 0.0          # Σw·(y − mean)²
        self.n_samples = 0     # finite samples with positive weight
        self.n_below = 0
        self.n_above = 0
        self.n_nonfinite = 0
        self.mass_outside = 0.0

    @property
    def grid(self) -> NDArray[np.float64]:
        return np.linspace(self.lo, self.hi, self.n_grid)

    @property
    def n_outside(self) -> int:
        return self.n_below + self.n_above

    def update(self, samples: ArrayLike, weights: ArrayLike | None = None) -> None:
        """Bin a block of samples. Non-finite samples (or weights) are counted in ``n_nonfinite``
        and skipped; samples outside ``[lo, hi]`` count in ``n_below``/``n_above`` and in the total
        mass (so the density integrates to the in-grid fraction) but are not binned. Samples with
        weight 0 are ignored."""
        y = np.asarray(samples, dtype=float).reshape(-1)
        w: NDArray[np.float64] | None = None         # None: unit weights (fast path)
        if weights is not None:
            w = np.asarray(weights, dtype=float).reshape(-1)
            if w.shape != y.shape:
                raise ValueError(f"StreamingKDE.add: weights shape {w.shape} != samples shape {y.shape}")
            if np.any(w < 0):
                raise ValueError("StreamingKDE.add: weights must be >= 0")
        finite = np.isfinite(y) if w is None else np.isfinite(y) & np.isfinite(w)
        if not finite.all():
            self.n_nonfinite += int(y.size - np.count_nonzero(finite))
            y = y[finite]
            w = None if w is None else w[finite]
        if w is not None and not (w > 0).all():
            y, w = y[w > 0], w[w > 0]
        if y.size == 0:
            return
        self._update_moments(y, w)
        if y.min() < self.lo or y.max() > self.hi:
            below, above = y < self.lo, y > self.hi
            self.n_below += int(np.count_nonzero(below))
            self.n_above += int(np.count_nonzero(above))
            inside = ~(below | above)
            self.mass_outside += float(np.count_nonzero(~inside) if w is None else w[~inside].sum())
            y = y[inside]
            w = None if w is None else w[inside]
        self._bin(y, w)

    def _bin(self, y: NDArray[np.float64], w: NDArray[np.float64] | None) -> None:
        """Linear binning of in-grid samples: a sample at ``t = (y − lo)/dx`` gives ``1 − frac`` of
        its mass to point ``floor(t)`` and ``frac`` to the next point."""
        if y.size == 0:
            return
        t = (y - self.lo) * (1.0 / self.dx)
        idx = t.astype(np.int64)                     # t >= 0, so truncation == floor
        frac = t - idx
        upper = frac if w is None else w * frac
        # only the span the block occupies: O(samples + span), not O(grid), per block (live blocks
        # hold a few dozen samples, the raw channel's capture grid 16384 points)
        first = int(idx.min())
        rel = idx - first
        span = int(rel.max()) + 2
        total = np.bincount(rel, weights=w, minlength=span)
        to_next = np.bincount(rel, weights=upper, minlength=span)
        counts = total - to_next
        counts[1:] += to_next[:-1]
        inside = self.n_grid - first
        if counts.size > inside:                     # round-off at y == hi lands past the end
            counts[inside - 1] += counts[inside:].sum()
            counts = counts[:inside]
        self.mass[first:first + counts.size] += counts

    def _update_moments(self, y: NDArray[np.float64], w: NDArray[np.float64] | None) -> None:
        """Chan et al. parallel combination of (Σw, mean, M2) with the block's own moments."""
        if w is None:
            wb = float(y.size)
            mean_b = float(y.mean())
            d = y - mean_b
            m2_b = float((d * d).sum())   # not np.dot: OpenBLAS threads spin on a busy machine
            w2_b = wb
        else:
            wb = float(w.sum())
            mean_b = float((w * y).sum() / wb)
            d = y - mean_b
            m2_b = float((w * d * d).sum())
            w2_b = float((w * w).sum())
        total = self.sum_w + wb
        delta = mean_b - self.mean
        self.mean += delta * wb / total
        self.m2 += m2_b + delta * delta * self.sum_w * wb / total
        self.sum_w = total
        self.sum_w2 += w2_b
        self.n_samples += int(y.size)

    # -- estimates ---------------------------------------------------------------------------
    @property
    def n_effective(self) -> float:
        """Kish's effective sample size ``(Σw)²/Σw²``."""
        return self.sum_w ** 2 / self.sum_w2 if self.sum_w2 > 0 else 0.0

    @property
    def std(self) -> float:
        """Weighted standard deviation of all finite samples (reliability weights; ddof = 1 for unit
        weights). 0.0 with fewer than 2 samples, and for constant data: a spread below the
        round-off of the running mean (``ROUNDOFF_SPREAD·|mean|``) counts as zero."""
        denom = self.sum_w - self.sum_w2 / self.sum_w if self.sum_w > 0 else 0.0
        if self.n_samples < 2 or denom <= 0:
            return 0.0
        std = math.sqrt(max(self.m2, 0.0) / denom)
        return std if std > ROUNDOFF_SPREAD * abs(self.mean) else 0.0

    @property
    def bandwidth(self) -> float:
        """Normal-reference bandwidth [unit of the data]; 0.0 if undefined."""
        n_eff, std = self.n_effective, self.std
        return normal_reference_bandwidth(n_eff, std) if n_eff > 0 and std > 0 else 0.0

    def density(self, bandwidth: float | None = None) -> NDArray[np.float64]:
        """Density on ``grid`` (per unit of the data), integrating to the in-grid mass fraction
        (less the kernel mass that spills over the grid ends). ``bandwidth`` overrides the rule.

        Raises :class:`KDEDataError` with fewer than 2 samples or zero spread.
        """
        if self.n_samples < 2:
            raise KDEDataError(f"StreamingKDE.density: need >= 2 finite samples, got {self.n_samples}")
        h = self.bandwidth if bandwidth is None else float(bandwidth)
        if not h > 0.0:
            raise KDEDataError("StreamingKDE.density: zero spread (constant data), bandwidth is 0")
        kernel = gaussian_kernel(h, self.dx, max_half_width=self.n_grid)
        smoothed = fftconvolve(self.mass, kernel, mode="same")
        np.maximum(smoothed, 0.0, out=smoothed)   # FFT round-off can give tiny negatives
        return smoothed / (self.sum_w * self.dx)

    def regrid(self, lo: float, hi: float, n_grid: int, shift: float = 0.0) -> "StreamingKDE":
        """A copy on another grid, of the data moved by ``−shift`` (same unit as the data): the
        binned mass, located at this grid's points minus ``shift``, is linearly re-binned; the
        running mean moves by ``−shift``, spread and counters are kept. Mass falling outside the new
        grid is counted as outside (by bin: ``n_below``/``n_above`` grow by the number of samples it
        represents, rounded). Used to move a provisional wide grid to the working grid, and with
        ``shift = mean`` to centre a window (a fractional-bin shift by linear interpolation).
        Linear binning conserves mass and first moment; each binning step adds at most ``dx²/4``
        of variance (of its own grid) per sample."""
        new = StreamingKDE(lo, hi, n_grid)
        for key in ("sum_w", "sum_w2", "mean", "m2", "n_samples", "n_below", "n_above",
                    "n_nonfinite", "mass_outside"):
            setattr(new, key, getattr(self, key))
        new.mean = self.mean - float(shift)
        occupied = self.mass > 0
        points, mass = self.grid[occupied] - float(shift), self.mass[occupied]
        below, above = points < lo, points > hi
        mean_w = self.sum_w / max(self.n_samples, 1)
        new.n_below += int(round(mass[below].sum() / mean_w)) if below.any() else 0
        new.n_above += int(round(mass[above].sum() / mean_w)) if above.any() else 0
        inside = ~(below | above)
        new.mass_outside += float(mass[~inside].sum())
        new._bin(points[inside], mass[inside])
        return new

    def occupied_range(self) -> tuple[float, float] | None:
        """``(lowest, highest)`` grid point holding mass, or None if nothing is binned."""
        nz = np.flatnonzero(self.mass > 0)
        if nz.size == 0:
            return None
        return float(self.lo + nz[0] * self.dx), float(self.lo + nz[-1] * self.dx)

    # -- persistence ------------------------------------------------------------------------
    def state_dict(self) -> dict[str, Any]:
        """JSON state. The mass is stored from its first to its last non-zero bin (``mass_offset``
        = index of the first): an empty window costs nothing, a fine grid only its occupied part."""
        nz = np.flatnonzero(self.mass)
        first, last = (int(nz[0]), int(nz[-1]) + 1) if nz.size else (0, 0)
        return {
            "lo": self.lo, "hi": self.hi, "n_grid": self.n_grid,
            "mass": self.mass[first:last].tolist(), "mass_offset": first,
            "sum_w": self.sum_w, "sum_w2": self.sum_w2, "mean": self.mean, "m2": self.m2,
            "n_samples": self.n_samples, "n_below": self.n_below, "n_above": self.n_above,
            "n_nonfinite": self.n_nonfinite, "mass_outside": self.mass_outside,
        }

    @classmethod
    def from_state(cls, state: dict[str, Any]) -> "StreamingKDE":
        n_grid = int(state["n_grid"])
        if not 2 <= n_grid <= MAX_GRID:       # a corrupted size must not allocate gigabytes
            raise ValueError(f"StreamingKDE.from_state: n_grid = {n_grid} outside 2 … {MAX_GRID}")
        kde = cls(state["lo"], state["hi"], n_grid)
        mass = np.asarray(state["mass"], dtype=float).reshape(-1)
        offset = int(state.get("mass_offset", 0))      # states without it hold the full grid
        if "mass_offset" not in state and mass.size != kde.n_grid:
            raise ValueError(f"StreamingKDE.from_state: 'mass' has {mass.size} bins, expected {kde.n_grid}")
        if offset < 0 or offset + mass.size > kde.n_grid:
            raise ValueError(f"StreamingKDE.from_state: 'mass' bins {offset}…{offset + mass.size} "
                             f"exceed the grid of {kde.n_grid} points")
        kde.mass[offset:offset + mass.size] = mass
        for key in ("sum_w", "sum_w2", "mean", "m2", "mass_outside"):
            setattr(kde, key, float(state[key]))
        for key in ("n_samples", "n_below", "n_above", "n_nonfinite"):
            setattr(kde, key, int(state[key]))
        return kde
