"""Per-joint distribution-domain monitor: KL distance of each cycle's torque density to nominal (§4).

Per cycle, two streaming KDEs are fed block by block: ``raw`` bins the joint torque ``τ`` and
``weighted`` bins ``w(v)·τ`` (disturbance-rejecting weights of motor speed, see
:mod:`edge_monitor.features.disturbance_weights`). At ``end_cycle`` each gives a density and its symmetric KL
distance to the nominal density; these are ``kl.raw`` and ``kl.weighted`` of the symptom record.

Grid choice (bounded memory): while no grid is fixed, the cycle is binned
on a provisional grid over the full wire range of torque, ``[-1.6384, 1.6384]``, with
``PROVISIONAL_GRID`` = 16384 points (2e-4 = four wire quanta per bin; weighted values are within the
same range since 0 ≤ w < 1). At the end of the first valid nominal cycle the working grid is
``[lo − m, hi + m]`` with ``[lo, hi]`` the occupied range and ``m = max(0.25·(hi − lo), 4·h)``
(h = that cycle's bandwidth), clipped to the wire range; that cycle's mass is re-binned onto it
(positions move by ≤ 1e-4, far below any bandwidth seen in practice) so it still counts as a nominal
cycle (with centring, the raw channel's range and mass are those of the centred cycle). Later
samples outside the working grid are counted as tail mass; the density then integrates
to less than one, which raises the KL distance: a shift out of the nominal range is seen, not hidden.

Centring (``center=True``, default): within a cycle the load (gravity) torque at the test angle is
constant and friction enters as ±τf symmetrically, so a per-cycle load is a location shift of the
cycle's torque; wear changes the shape. Both channels are made exactly invariant to it:

* ``raw``: the cycle is binned on the fixed provisional grid (wire range, 16384 points, memory
  O(grid)) with its running mean; at cycle end the binned mass is moved by −(cycle mean) onto the
  working grid by linear interpolation (:meth:`StreamingKDE.regrid` with ``shift``). The density
  compared is that of ``τ − mean(τ)``. Error for a pure shift: two linear binnings, KL ≤ 1.5·δ²/h⁴
  with δ = (dx_capture² + dx_working²)/4 (derived in the tests).
* ``weighted``: the weight applies to centred torque, ``w(v)·(τ_t − m_t)``, with ``m_t`` the running
  mean of the cycle's finite torque samples up to sample t (causal). Exact centring by the final
  cycle mean before weighting is impossible in one pass with O(grid) memory (``w·(τ − m)`` is not a
  shift of the ``w·τ`` histogram: it needs the joint histogram of (w, w·τ)), and centring after
  weighting does not remove the load (``w·l`` spreads with w). The causal mean removes a per-cycle
  constant exactly (it shifts ``τ_t`` and ``m_t`` alike), at the price that early samples are
  centred on a noisier location; nominal and test cycles pass the same transform.

``center=False`` reproduces the uncentred detector (densities of τ and w·τ themselves).

Nominal model: the average of the densities of the first K valid cycles (``n_nominal_cycles``),
relearned (grid included) after :meth:`KLMonitor.reset` (declared gearbox replacement). The simple
threshold ``μ0 + 3σ0`` uses leave-one-out KL values of the K learning cycles (each against the
average of the other K − 1), so it is not biased low by comparing a cycle with itself.

Units: torque dimensionless (fraction of max. joint torque), speed rad/s, KL dimensionless.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, field
from typing import Any, Literal

import numpy as np
from numpy.typing import ArrayLike, NDArray

from edge_monitor.features.disturbance_weights import WeightFunction
from protocol.frames import SEGMENT_PRODUCTION, TORQUE_SCALE
from edge_monitor.stats.kde_stream import StreamingKDE, choose_grid, symmetric_kl

log = logging.getLogger(__name__)

#: Wire range of torque (docs/PROTOCOL.md: 16-bit signed): ±1.6384.
TORQUE_WIRE_LIMIT = TORQUE_SCALE * (1 << 15)
#: Points of the provisional grid used until the working grid is fixed.
PROVISIONAL_GRID = 16384
#: Grid margin: fraction of the occupied range, and minimum in bandwidths of the first cycle.
GRID_MARGIN = 0.25
GRID_MIN_MARGIN_BANDWIDTHS = 4.0

Window = Literal["cycle", "production"]
CHANNELS = ("raw", "weighted")


class KLConfigError(ValueError):
    """Invalid KLMonitor configuration."""


@dataclass
class KLResult:
    """Outcome of one cycle. ``raw``/``weighted`` are None while learning or when the cycle is
    unusable; ``reason`` then says why (e.g. ``"cycle too short: 12 samples < 1000"``)."""

    cycle: int
    raw: float | None = None
    weighted: float | None = None
    reason: str | None = None
    n_samples: int = 0
    #: per channel: {"below", "above", "nonfinite"} sample counts of this cycle
    outside: dict[str, dict[str, int]] = field(default_factory=dict)
    #: {"raw": μ0 + 3σ0, "weighted": ...} once the nominal model is learned, else None
    threshold_3sigma: dict[str, float] | None = None
    nearest_mode: str | None = None
    #: raw channel for plotting: {"grid", "cycle", "nominal"} (ndarrays; nominal None while learning)
    density: dict[str, NDArray[np.float64] | None] | None = None

    def to_record(self) -> dict[str, float | None]:
        """The ``kl`` part of the symptom record."""
        return {"raw": self.raw, "weighted": self.weighted}


class _Channel:
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
                             min_margin=max(GRID_MIN_MARGIN_BANDWIDTHS * self.kde.bandwidth, 10 * 5e-5),
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
        return None if self.mu0 is None else self.mu0 + 3.0 * self.sigma0

    def new_window(self) -> None:
        self.kde.reset()

    def state_dict(self) -> dict[str, Any]:
        return {"kde": self.kde.state_dict(), "grid_fixed": self.grid_fixed, "lo": self.lo, "hi": self.hi,
                "learning": [d.tolist() for d in self.learning],
                "nominal": None if self.nominal is None else self.nominal.tolist(),
                "mu0": self.mu0, "sigma0": self.sigma0}

    @classmethod
    def from_state(cls, n_grid: int, center: bool, state: dict[str, Any]) -> "_Channel":
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


class KLMonitor:
    """Distribution-domain detector of one joint. Feed blocks with :meth:`add`, close each cycle
    with :meth:`end_cycle`.

    ``window="cycle"`` uses every sample of the cycle, ``"production"`` only samples whose segment
    code is 200 (production motion). ``weights=None`` disables the weighted channel. ``center=True``
    compares the densities of the cycle's values minus their own cycle mean (invariant to a
    per-cycle load/gravity torque); ``False`` compares the densities of the values themselves.
    """

    def __init__(self, n_nominal_cycles: int = 10, n_grid: int = 512,
                 weights: WeightFunction | None = WeightFunction(), window: Window = "cycle",
                 min_samples: int = 1000, center: bool = True) -> None:
        if int(n_nominal_cycles) < 2:
            raise KLConfigError(f"n_nominal_cycles: need >= 2 (for σ0), got {n_nominal_cycles}")
        if int(n_grid) < 64:
            raise KLConfigError(f"n_grid: need >= 64 grid points, got {n_grid}")
        if window not in ("cycle", "production"):
            raise KLConfigError(f"window: must be 'cycle' or 'production', got {window!r}")
        if int(min_samples) < 2:
            raise KLConfigError(f"min_samples: need >= 2, got {min_samples}")
        self.n_nominal_cycles = int(n_nominal_cycles)
        self.n_grid = int(n_grid)
        self.weights = weights
        self.window: Window = window
        self.min_samples = int(min_samples)
        self.center = bool(center)
        self.modes: dict[str, NDArray[np.float64]] = {}
        self.reset()

    # -- configuration / lifecycle ------------------------------------------------------------
    @property
    def channel_names(self) -> tuple[str, ...]:
        return CHANNELS if self.weights is not None else CHANNELS[:1]

    def reset(self) -> None:
        """Forget grid, nominal model and stored modes (they live on the old grid), e.g. after a
        declared gearbox replacement; the next valid cycles relearn them."""
        self.channels = {name: _Channel(self.n_grid, self._centred_by_mean(name)) for name in self.channel_names}
        self.n_learned = 0
        self._new_window()

    def _new_window(self) -> None:
        self.n_window = 0          # samples that entered the window this cycle (before NaN checks)
        self.torque_sum = 0.0      # Σ finite τ of the window so far (causal location, weighted channel)
        self.torque_count = 0

    def _centred_by_mean(self, channel: str) -> bool:
        """The raw channel is centred by its cycle mean at cycle end; the weighted channel bins
        values already centred causally (see :meth:`_causally_centred`)."""
        return self.center and channel == "raw"

    def _causally_centred(self, tau: NDArray[np.float64]) -> NDArray[np.float64]:
        """``τ_t − m_t`` with ``m_t`` the mean of the window's finite torque samples up to and
        including t (updates the running sums). A per-cycle constant load adds the same constant to
        ``τ_t`` and ``m_t``, so the result is exactly invariant to it. Non-finite τ stay non-finite."""
        finite = np.isfinite(tau)
        sums = self.torque_sum + np.cumsum(np.where(finite, tau, 0.0))
        counts = self.torque_count + np.cumsum(finite)
        if tau.size:
            self.torque_sum, self.torque_count = float(sums[-1]), int(counts[-1])
        return tau - sums / np.maximum(counts, 1)
        self.modes = {}

    @property
    def learned(self) -> bool:
        return self.n_learned >= self.n_nominal_cycles

    @property
    def grid(self) -> NDArray[np.float64] | None:
        raw = self.channels["raw"]
        return raw.grid if raw.grid_fixed else None

    def add_mode(self, name: str, density: ArrayLike) -> None:
        """Store the raw-channel density of a known mode (on this monitor's working grid)."""
        if self.grid is None:
            raise KLConfigError("add_mode: the working grid is not fixed yet (learn nominal cycles first)")
        d = np.asarray(density, dtype=float)
        if d.shape != (self.n_grid,) or not np.all(np.isfinite(d)) or np.any(d < 0):
            raise KLConfigError(f"add_mode({name!r}): need {self.n_grid} finite non-negative density values")
        self.modes[str(name)] = d

    # -- streaming ----------------------------------------------------------------------------
    def add(self, torque: ArrayLike, speed: ArrayLike, segment: ArrayLike | None = None) -> None:
        """Add a block of samples of this joint (torque dimensionless, speed rad/s, segment codes)."""
        tau = np.asarray(torque, dtype=float).reshape(-1)
        v = np.asarray(speed, dtype=float).reshape(-1)
        if v.shape != tau.shape:
            raise ValueError(f"KLMonitor.add: speed has {v.size} samples, torque {tau.size}")
        if self.window == "production":
            if segment is None:
                return                       # no segment information: nothing is production
            seg = np.asarray(segment).reshape(-1)
            if seg.shape != tau.shape:
                raise ValueError(f"KLMonitor.add: segment has {seg.size} samples, torque {tau.size}")
            keep = seg == SEGMENT_PRODUCTION
            tau, v = tau[keep], v[keep]
        self.n_window += tau.size
        self.channels["raw"].kde.add(tau)
        if self.weights is not None:
            located = self._causally_centred(tau) if self.center else tau
            self.channels["weighted"].kde.add(self.weights(v) * located)

    def discard_cycle(self) -> None:
        """Drop the open window without evaluating or learning (partial or duplicate cycles)."""
        for ch in self.channels.values():
            ch.new_window()
        self._new_window()

    def end_cycle(self, cycle: int) -> KLResult:
        """Close the cycle: density, KL distances (or learning step, or a reason) and a new window."""
        try:
            return self._evaluate(int(cycle))
        finally:
            for ch in self.channels.values():
                ch.new_window()
            self._new_window()

    def _outside(self) -> dict[str, dict[str, int]]:
        return {name: {"below": ch.kde.n_below, "above": ch.kde.n_above, "nonfinite": ch.kde.n_nonfinite}
                for name, ch in self.channels.items()}

    def _unusable(self) -> str | None:
        """Why this cycle cannot give a KL value, or None if it can."""
        if self.n_window == 0:
            return "empty window: no samples" + (" in the production segment" if self.window == "production" else "")
        counts = [ch.kde.n_samples for ch in self.channels.values()]
        if min(counts) < self.min_samples:
            nonfinite = max(ch.kde.n_nonfinite for ch in self.channels.values())
            extra = f" ({nonfinite} non-finite skipped)" if nonfinite else ""
            return f"cycle too short: {min(counts)} samples < {self.min_samples}{extra}"
        for name, ch in self.channels.items():
            if not ch.kde.bandwidth > 0:
                return "constant data" if name == "raw" else f"constant data ({name})"
        return None

    def _evaluate(self, cycle: int) -> KLResult:
        result = KLResult(cycle=cycle, n_samples=self.channels["raw"].kde.n_samples, outside=self._outside())
        reason = self._unusable()
        if reason is not None:
            result.reason = reason
            log.info("cycle %d: no KL value: %s", cycle, reason)
            return result
        for ch in self.channels.values():
            if not ch.grid_fixed:
                ch.fix_grid()
        windows = {name: ch.window_kde() for name, ch in self.channels.items()}
        # regrid (first cycle, or centring) may move mass outside the working grid
        result.outside = {name: {"below": k.n_below, "above": k.n_above, "nonfinite": k.n_nonfinite}
                          for name, k in windows.items()}
        densities = {name: k.density() for name, k in windows.items()}
        raw = self.channels["raw"]
        if not self.learned:
            for name, ch in self.channels.items():
                ch.learning.append(densities[name])
            self.n_learned += 1
            result.reason = f"learning {self.n_learned}/{self.n_nominal_cycles}"
            if self.learned:
                for ch in self.channels.values():
                    ch.finish_learning()
            result.density = {"grid": raw.grid, "cycle": densities["raw"], "nominal": raw.nominal}
            result.threshold_3sigma = self._thresholds()
            return result
        values = {name: symmetric_kl(ch.nominal, densities[name], ch.dx) for name, ch in self.channels.items()}
        result.raw = values["raw"]
        result.weighted = values.get("weighted")
        result.threshold_3sigma = self._thresholds()
        result.nearest_mode = self._nearest_mode(densities["raw"])
        result.density = {"grid": raw.grid, "cycle": densities["raw"], "nominal": raw.nominal}
        return result

    def _thresholds(self) -> dict[str, float] | None:
        if not self.learned:
            return None
        return {name: float(ch.threshold) for name, ch in self.channels.items()}  # type: ignore[arg-type]

    def _nearest_mode(self, density: NDArray[np.float64]) -> str | None:
        """``argmin_m KL(p_m, p_k)`` over the stored modes and ``"nominal"``; None without stored modes."""
        if not self.modes:
            return None
        raw = self.channels["raw"]
        candidates = {"nominal": raw.nominal, **self.modes}
        distances = {name: symmetric_kl(d, density, raw.dx) for name, d in candidates.items()}
        return min(distances, key=distances.__getitem__)

    # -- persistence ------------------------------------------------------------------------
    def state_dict(self) -> dict[str, Any]:
        return {
            "n_nominal_cycles": self.n_nominal_cycles, "n_grid": self.n_grid,
            "weights": None if self.weights is None else self.weights.to_dict(),
            "window": self.window, "min_samples": self.min_samples, "center": self.center,
            "n_learned": self.n_learned, "n_window": self.n_window,
            "torque_sum": self.torque_sum, "torque_count": self.torque_count,
            "channels": {name: ch.state_dict() for name, ch in self.channels.items()},
            "modes": {name: d.tolist() for name, d in self.modes.items()},
        }

    @classmethod
    def from_state(cls, state: dict[str, Any]) -> "KLMonitor":
        weights = None if state["weights"] is None else WeightFunction.from_dict(state["weights"])
        # states written before centring existed learned uncentred densities: missing key → False
        mon = cls(n_nominal_cycles=state["n_nominal_cycles"], n_grid=state["n_grid"], weights=weights,
                  window=state["window"], min_samples=state["min_samples"],
                  center=bool(state.get("center", False)))
        mon.n_learned = int(state["n_learned"])
        mon.n_window = int(state["n_window"])
        mon.torque_sum = float(state.get("torque_sum", 0.0))
        mon.torque_count = int(state.get("torque_count", 0))
        mon.channels = {name: _Channel.from_state(mon.n_grid, mon._centred_by_mean(name), s)
                        for name, s in state["channels"].items()}
        mon.modes = {name: np.asarray(d, dtype=float) for name, d in state["modes"].items()}
        return mon
