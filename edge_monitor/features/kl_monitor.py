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

Slow samples (``min_speed``, default 10 rad/s) are left out of both channels. At standstill the
friction is static, of a sign the speed cannot tell. Below ≈ 10 rad/s (the Stribeck region) the
lubricant temperature moves the torque in a way the temperature compensation cannot undo: there the
speed loop's response to the temperature-dependent Stribeck friction changes the samples themselves,
and the compensated torque of a 55 °C cycle differs from the same cycle at 35 °C by as much as without
compensation (1–5 rad/s) or a third of it (5–10 rad/s), against ≤ 13 % above 10 rad/s
(``tools/warmup_drift_study.py --part residual``). With 1 rad/s the raw KL distance of a healthy joint
rose by +0.5 … +1.2 σ over a warm-up from 35 to 55 °C; the wear's Stribeck term reaches speeds of
ϖ·vsϖ (≈ 40 rad/s at wear 20), so the wear stays visible above 10 rad/s (docs/KL_DETECTOR.md).

Nominal model: the average of the densities of the first K valid cycles (``n_nominal_cycles``),
relearned (grid included) after :meth:`KLMonitor.reset` (declared gearbox replacement). The simple
threshold ``μ0 + 3σ0`` uses leave-one-out KL values of the K learning cycles (each against the
average of the other K − 1), so it is not biased low by comparing a cycle with itself.

Units: torque dimensionless (fraction of max. joint torque), speed rad/s, KL dimensionless.
"""

from __future__ import annotations

import logging
import math
from dataclasses import asdict, dataclass, field
from typing import Any, Literal, Mapping

import numpy as np
from numpy.typing import ArrayLike, NDArray

from edge_monitor.errors import check_learned_with, require
from edge_monitor.features.base import CycleInput, FeatureOutput
from edge_monitor.features.disturbance_weights import DEFAULT_ALPHA, DEFAULT_BETA, WeightFunction
from edge_monitor.features.kl_channel import KLChannel
from edge_monitor.features.temperature_compensation import TemperatureCompensation
from edge_monitor.records import finite_or_none
from edge_monitor.stats.kde_stream import MAX_GRID, symmetric_kl
from joint_model import FrictionParams
from protocol.frames import SEGMENT_PRODUCTION

log = logging.getLogger(__name__)

Window = Literal["cycle", "production"]
CHANNELS = ("raw", "weighted")
#: Section of a symptom when there is no KL value (feature off, or a partial cycle).
EMPTY_SECTION: dict[str, Any] = {"raw": None, "weighted": None}


@dataclass(frozen=True)
class KLConfig:
    """Distribution-domain detector settings (the ``[kl]`` table), validated once, here.

    ``window``: "cycle" (every sample) or "production" (segment 200 only); ``center``: compare
    densities of torque − cycle mean; ``alpha``, ``beta`` [s/rad]: weights w(v) = sech(β·v)·tanh(α·v);
    ``min_samples``: fewest samples a cycle needs for a KL value.
    """

    enabled: bool = True
    n_nominal_cycles: int = 10
    n_grid: int = 512
    window: str = "cycle"
    center: bool = True
    temperature_compensation: bool = True   # move samples to the reference temperature (needs the wear feature)
    min_speed: float = 10.0                 # [rad/s] slower samples are left out (module docstring)
    alpha: float = DEFAULT_ALPHA
    beta: float = DEFAULT_BETA
    min_samples: int = 1000

    def __post_init__(self) -> None:
        require(2 <= self.n_nominal_cycles <= 1000, "kl.n_nominal_cycles",
                f"need 2 … 1000 cycles (2 for σ0), got {self.n_nominal_cycles}")
        require(64 <= self.n_grid <= MAX_GRID, "kl.n_grid", f"need 64 … {MAX_GRID} grid points, got {self.n_grid}")
        require(self.window in ("cycle", "production"), "kl.window",
                f"must be 'cycle' or 'production', got {self.window!r}")
        for name in ("alpha", "beta"):
            value = getattr(self, name)
            require(math.isfinite(value) and 0 <= value <= 10, f"kl.{name}", f"must be 0 … 10 s/rad, got {value}")
        require(2 <= self.min_samples <= 10_000_000, "kl.min_samples", f"need 2 … 1e7, got {self.min_samples}")
        require(math.isfinite(self.min_speed) and 0 <= self.min_speed <= 100, "kl.min_speed",
                f"must be 0 … 100 rad/s, got {self.min_speed}")

    def fingerprint(self) -> dict[str, Any]:
        """The settings the learned grid and nominal densities depend on."""
        out = asdict(self)
        del out["enabled"]
        return out

    @property
    def weights(self) -> WeightFunction:
        return WeightFunction(alpha=self.alpha, beta=self.beta)


@dataclass
class KLResult:
    """Outcome of one cycle. ``raw``/``weighted`` are None while learning or when the cycle is
    unusable; ``reason`` then says why (e.g. ``"cycle too short: 12 samples < 1000"``)."""

    cycle: int
    raw: float | None = None
    weighted: float | None = None
    reason: str | None = None
    n_samples: int = 0
    #: samples left out as too slow (|v| < ``kl.min_speed``: standstill and the Stribeck region)
    standstill: int = 0
    #: per channel: {"below", "above", "nonfinite"} sample counts of this cycle
    outside: dict[str, dict[str, int]] = field(default_factory=dict)
    #: {"raw": μ0 + 3σ0, "weighted": ...} once the nominal model is learned, else None
    threshold_3sigma: dict[str, float] | None = None
    nearest_mode: str | None = None
    #: raw channel for plotting: {"grid", "cycle", "nominal"} (ndarrays; nominal None while learning)
    density: dict[str, NDArray[np.float64] | None] | None = None

    def to_section(self) -> dict[str, Any]:
        """The ``"kl"`` section of the symptom record: raw/weighted KL, the μ0 + 3σ0 thresholds, the
        samples outside the grid, the nearest stored mode and the number of samples."""
        out: dict[str, Any] = {"raw": finite_or_none(self.raw), "weighted": finite_or_none(self.weighted)}
        if self.threshold_3sigma:
            out["threshold_3sigma"] = {k: finite_or_none(v) for k, v in self.threshold_3sigma.items()}
        if self.outside:
            out["outside"] = self.outside
        if self.standstill:
            out["standstill"] = self.standstill
        if self.nearest_mode is not None:
            out["nearest_mode"] = self.nearest_mode
        out["n_samples"] = self.n_samples
        return out


class KLMonitor:
    """Distribution-domain detector of one joint. Feed sample blocks with :meth:`update`, close each
    cycle with :meth:`end_cycle`.

    ``window="cycle"`` uses every sample of the cycle, ``"production"`` only samples whose segment
    code is 200 (production motion). ``center=True`` compares the densities of the cycle's values
    minus their own cycle mean (invariant to a per-cycle load/gravity torque); ``False`` compares the
    densities of the values themselves.
    """

    name = "kl"
    quantities = ("kl_raw", "kl_weighted")

    def __init__(self, config: KLConfig = KLConfig(), params: FrictionParams | None = None) -> None:
        self.config = config
        self.params = params
        self.compensation = TemperatureCompensation(params) \
            if config.temperature_compensation and params is not None else None
        self.n_nominal_cycles = config.n_nominal_cycles
        self.n_grid = config.n_grid
        self.weights: WeightFunction | None = config.weights
        self.window: Window = config.window  # type: ignore[assignment]
        self.min_samples = config.min_samples
        self.center = config.center
        self.min_speed = config.min_speed
        self.reset()

    # -- configuration / lifecycle ------------------------------------------------------------
    @property
    def channel_names(self) -> tuple[str, ...]:
        return CHANNELS if self.weights is not None else CHANNELS[:1]

    def reset(self) -> None:
        """Forget grid, nominal model and stored modes (they live on the old grid), e.g. after a
        declared gearbox replacement; the next valid cycles relearn them."""
        self.channels = {name: KLChannel(self.n_grid, self._centred_by_mean(name)) for name in self.channel_names}
        self.modes: dict[str, NDArray[np.float64]] = {}
        self.n_learned = 0
        if self.compensation is not None:
            self.compensation.reset()
        self._new_window()

    def _new_window(self) -> None:
        self.n_window = 0          # samples that entered the window this cycle (before NaN checks)
        self.n_standstill = 0      # of these, left out as standstill (|v| < min_speed)
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
            raise ValueError("add_mode: the working grid is not fixed yet (learn nominal cycles first)")
        d = np.asarray(density, dtype=float)
        if d.shape != (self.n_grid,) or not np.all(np.isfinite(d)) or np.any(d < 0):
            raise ValueError(f"add_mode({name!r}): need {self.n_grid} finite non-negative density values")
        self.modes[str(name)] = d

    # -- streaming ----------------------------------------------------------------------------
    def update_samples(self, torque: ArrayLike, speed: ArrayLike, segment: ArrayLike | None = None) -> None:
        """Bin a block of samples of this joint (torque dimensionless, speed rad/s, segment codes)."""
        tau = np.asarray(torque, dtype=float).reshape(-1)
        v = np.asarray(speed, dtype=float).reshape(-1)
        if v.shape != tau.shape:
            raise ValueError(f"KLMonitor.update_samples: speed has {v.size} samples, torque {tau.size}")
        if self.window == "production":
            if segment is None:
                return                       # no segment information: nothing is production
            seg = np.asarray(segment).reshape(-1)
            if seg.shape != tau.shape:
                raise ValueError(f"KLMonitor.update_samples: segment has {seg.size} samples, torque {tau.size}")
            keep = seg == SEGMENT_PRODUCTION
            tau, v = tau[keep], v[keep]
        self.n_window += tau.size
        if self.min_speed > 0:           # standstill: static friction, of a sign the speed cannot tell
            still = np.abs(v) < self.min_speed          # NaN speeds stay in and are counted as non-finite
            self.n_standstill += int(still.sum())
            tau, v = tau[~still], v[~still]
        if self.compensation is not None:
            tau = self.compensation.apply(tau, v)
        self.channels["raw"].kde.update(tau)
        if self.weights is not None:
            located = self._causally_centred(tau) if self.center else tau
            self.channels["weighted"].kde.update(self.weights(v) * located)

    def update(self, cycle: CycleInput, context: Mapping[str, float] | None = None) -> FeatureOutput:
        """The feature step (:class:`~edge_monitor.features.base.Feature`): close the cycle and give the
        ``"kl"`` section, the quantities ``kl_raw``/``kl_weighted`` and the raw density for viewers. A
        partial cycle is discarded (its window lacks the cycle's start). The ``temperature`` of the
        context (the wear feature's ξ̂) updates the temperature compensation of the next cycles."""
        if self.compensation is not None:
            self.compensation.observe((context or {}).get("temperature"))
        if cycle.partial:
            self.discard_cycle()
            return FeatureOutput(section=dict(EMPTY_SECTION), values={q: math.nan for q in self.quantities})
        result = self.end_cycle(cycle.cycle)
        values = {"kl_raw": _nan_if_none(result.raw), "kl_weighted": _nan_if_none(result.weighted)}
        extras = {"density": result.density} if result.density is not None else {}
        return FeatureOutput(section=result.to_section(), values=values, reason=result.reason, extras=extras)

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
        if self.n_standstill == self.n_window:
            return f"joint too slow: all {self.n_window} samples slower than kl.min_speed = {self.min_speed:g} rad/s"
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
        result = KLResult(cycle=cycle, n_samples=self.channels["raw"].kde.n_samples, outside=self._outside(),
                          standstill=self.n_standstill)
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
        values = {name: symmetric_kl(_learned(ch.nominal), densities[name], ch.dx)
                  for name, ch in self.channels.items()}
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
        candidates = {"nominal": _learned(raw.nominal), **self.modes}
        distances = {name: symmetric_kl(d, density, raw.dx) for name, d in candidates.items()}
        return min(distances, key=distances.__getitem__)

    # -- persistence ------------------------------------------------------------------------
    def state_dict(self) -> dict[str, Any]:
        """Learned grid and nominal densities, the open window, and the config they were learned with."""
        return {
            "config": self.fingerprint(),
            "compensation": None if self.compensation is None else self.compensation.state_dict(),
            "n_learned": self.n_learned, "n_window": self.n_window, "n_standstill": self.n_standstill,
            "torque_sum": self.torque_sum, "torque_count": self.torque_count,
            "channels": {name: ch.state_dict() for name, ch in self.channels.items()},
            "modes": {name: d.tolist() for name, d in self.modes.items()},
        }

    def fingerprint(self) -> dict[str, Any]:
        """What the learned densities depend on: the config, and the friction model that compensates
        temperature (when it does)."""
        out = self.config.fingerprint()
        if self.compensation is not None and self.params is not None:
            out["friction"] = self.params.to_dict()
        return out

    @classmethod
    def from_state(cls, config: KLConfig, state: dict[str, Any], params: FrictionParams | None = None) -> "KLMonitor":
        """Restore a monitor learned with ``config``; :class:`StateMismatch` if it was learned with another."""
        mon = cls(config, params)
        check_learned_with("kl", state, mon.fingerprint())
        if mon.compensation is not None and isinstance(state.get("compensation"), dict):
            mon.compensation.load_state(state["compensation"])
        mon.n_learned = int(state["n_learned"])
        mon.n_window = int(state["n_window"])
        mon.n_standstill = int(state.get("n_standstill", 0))
        mon.torque_sum = float(state.get("torque_sum", 0.0))
        mon.torque_count = int(state.get("torque_count", 0))
        mon.channels = {name: KLChannel.from_state(mon.n_grid, mon._centred_by_mean(name), state["channels"][name])
                        for name in mon.channel_names}
        mon.modes = {name: np.asarray(d, dtype=float) for name, d in state["modes"].items()}
        return mon


def _learned(nominal: NDArray[np.float64] | None) -> NDArray[np.float64]:
    """The nominal density of a channel that has finished learning."""
    assert nominal is not None, "nominal density used before learning finished"
    return nominal


def _nan_if_none(x: float | None) -> float:
    value = finite_or_none(x)
    return math.nan if value is None else value
