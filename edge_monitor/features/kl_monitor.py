"""Per-joint distribution-domain monitor: KL distance of each cycle's torque density to nominal (§4).

Per cycle, two streaming KDEs are fed block by block: ``raw`` bins the joint torque ``τ`` and
``weighted`` bins ``w(v)·τ`` (disturbance-rejecting weights of motor speed,
:mod:`edge_monitor.features.disturbance_weights`). At ``end_cycle`` each gives a density and its
symmetric KL distance to the nominal density: ``kl.raw`` and ``kl.weighted`` of the symptom record.
docs/KL_DETECTOR.md ("How it works") derives each step; in short:

* **Window** (``window``): by default the test cycle's segments only (the constant-speed moves and
  their ramps). The production motion carries the robot's own dynamics (a gravity profile scaled by
  the payload) that the agent has no model of, so a payload change would look like wear there.
* **Grid** (bounded memory): a provisional grid over the wire range (``PROVISIONAL_GRID`` points)
  until the first valid nominal cycle fixes the working grid (occupied range plus a margin); later
  samples outside it count as tail mass, which raises the KL distance: a shift is seen, not hidden.
* **Centring** (``center``): the load torque at the test angle is constant within a cycle, a location
  shift; ``raw`` compares the density of ``τ − mean(τ)`` (moved at the cycle's end, linear
  interpolation), ``weighted`` bins ``w(v)·(τ_t − m_t)`` with the causal running mean ``m_t`` (exact
  centring before weighting would need the joint histogram of (w, w·τ)).
* **Compensation**: temperature (:mod:`~edge_monitor.features.temperature_compensation`, per sample
  with the previous cycles' ξ̂, or without a motor temperature the joint's thermal model driven by the
  cycles' power ⟨τ·v⟩, :class:`~edge_monitor.features.lubricant_thermal_filter.CycleHeat`) and load
  (:mod:`~edge_monitor.features.load_compensation`, at the
  cycle's end with its measured load torque, through a :class:`~edge_monitor.stats.sliced_kde.SlicedKDE`
  capture), both with the joint's own friction model, so the densities are those of the reference
  temperature and load.
* **Slow samples** (``min_speed``, 10 rad/s) are left out: at standstill friction is static, and below
  ≈ 10 rad/s the speed loop's response to the Stribeck friction changes the samples themselves in a
  way no temperature compensation undoes.
* **Nominal**: the average density of the first ``n_nominal_cycles`` valid cycles, relearned (grid
  included) after :meth:`KLMonitor.reset`; ``μ0 + 3σ0`` from their leave-one-out KL values.

Units: torque dimensionless (fraction of max. joint torque), speed rad/s, KL dimensionless.
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass, field
from typing import Any, Mapping

import numpy as np
from numpy.typing import ArrayLike, NDArray

from edge_monitor.errors import check_learned_with
from edge_monitor.features.base import CycleInput, FeatureOutput
from edge_monitor.features.disturbance_weights import WeightFunction
from edge_monitor.features.kl_channel import KLChannel
from edge_monitor.features.kl_config import LOAD_COMPENSATION, WINDOWS, KLConfig, Window  # noqa: F401 (re-exported)
from edge_monitor.features.load_compensation import LoadCompensation
from edge_monitor.features.lubricant_thermal_filter import CycleHeat
from edge_monitor.features.temperature_compensation import TemperatureCompensation
from edge_monitor.records import finite_or_none
from edge_monitor.stats.kde_stream import symmetric_kl
from joint_model import FrictionParams
from protocol.frames import SEGMENT_PRODUCTION

log = logging.getLogger(__name__)

CHANNELS = ("raw", "weighted")
#: Section of a symptom when there is no KL value (feature off, or a partial cycle).
EMPTY_SECTION: dict[str, Any] = {"raw": None, "weighted": None}


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
    #: load compensation of this cycle: {"value", "reference", "source"} (|load torque|, dimensionless)
    load: dict[str, Any] | None = None

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
        if self.load is not None:
            out["load"] = self.load
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

    def __init__(self, config: KLConfig | None = None, params: FrictionParams | None = None) -> None:
        self.config = config = config or KLConfig()
        self.params = params
        self.compensation = TemperatureCompensation(params, time_constant_s=3600.0 * config.cooling_time_constant_h) \
            if config.temperature_compensation and params is not None else None
        self.heat = CycleHeat()
        self.n_nominal_cycles = config.n_nominal_cycles
        self.n_grid = config.n_grid
        self.weights: WeightFunction | None = config.weights
        self.window: Window = config.window  # type: ignore[assignment]
        self.min_samples = config.min_samples
        self.center = config.center
        self.min_speed = config.min_speed
        self.load = LoadCompensation(params, config.load_compensation) \
            if config.load_compensation != "off" and params is not None else None
        self.reset()

    # -- configuration / lifecycle ------------------------------------------------------------
    @property
    def channel_names(self) -> tuple[str, ...]:
        return CHANNELS if self.weights is not None else CHANNELS[:1]

    def reset(self) -> None:
        """Forget grid, nominal model and stored modes (they live on the old grid), e.g. after a
        declared gearbox replacement; the next valid cycles relearn them."""
        self.channels = {name: KLChannel(self.n_grid, self._centred_by_mean(name), self._coefficient_bound(name))
                         for name in self.channel_names}
        self.modes: dict[str, NDArray[np.float64]] = {}
        self.n_learned = 0
        if self.load is not None:
            self.load.reset()
        if self.compensation is not None:
            self.compensation.reset()
        self._new_window()

    def _new_window(self) -> None:
        self.n_window = 0          # samples that entered the window this cycle (before NaN checks)
        self.n_standstill = 0      # of these, left out as standstill (|v| < min_speed)
        self.torque_sum = 0.0      # Σ finite τ of the window so far (causal location, weighted channel)
        self.torque_count = 0
        self.coefficient_sum = 0.0     # Σ load coefficients of those samples (their causal mean)

    def _centred_by_mean(self, channel: str) -> bool:
        """The raw channel is centred by its cycle mean at cycle end; the weighted channel bins
        values already centred causally (see :meth:`_causally_centred`)."""
        return self.center and channel == "raw"

    def _coefficient_bound(self, channel: str) -> float:
        """Largest |load coefficient| a sample of ``channel`` carries (0: no load compensation)."""
        if self.load is None:
            return 0.0
        return self.load.bound(self.min_speed, self.weights if channel == "weighted" else None)

    def _causally_centred(self, tau: NDArray[np.float64], coef: NDArray[np.float64] | None
                          ) -> tuple[NDArray[np.float64], NDArray[np.float64] | None]:
        """``τ_t − m_t`` with ``m_t`` the mean of the window's finite torque samples up to and
        including t (updates the running sums), and the load coefficients centred alike,
        ``c_t − C_t``. A per-cycle constant load adds the same constant to ``τ_t`` and ``m_t``, so the
        result is exactly invariant to it; a load change ε moves ``τ_t − m_t`` by ``ε·(c_t − C_t)``.
        Non-finite τ stay non-finite."""
        finite = np.isfinite(tau)
        sums = self.torque_sum + np.cumsum(np.where(finite, tau, 0.0))
        counts = self.torque_count + np.cumsum(finite)
        centred_coef = None
        if coef is not None:
            coef_sums = self.coefficient_sum + np.cumsum(np.where(finite, coef, 0.0))
            centred_coef = coef - coef_sums / np.maximum(counts, 1)
            if tau.size:
                self.coefficient_sum = float(coef_sums[-1])
        if tau.size:
            self.torque_sum, self.torque_count = float(sums[-1]), int(counts[-1])
        return tau - sums / np.maximum(counts, 1), centred_coef

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
        self.heat.add(tau, v)
        if self.window != "cycle":
            if segment is None and self.window == "production":
                return                       # no segment information: nothing is production
            if segment is not None:          # without segment codes every sample is the test's
                seg = np.asarray(segment).reshape(-1)
                if seg.shape != tau.shape:
                    raise ValueError(f"KLMonitor.update_samples: segment has {seg.size} samples, torque {tau.size}")
                keep = (seg == SEGMENT_PRODUCTION) if self.window == "production" else (seg != SEGMENT_PRODUCTION)
                tau, v = tau[keep], v[keep]
        self.n_window += tau.size
        if self.min_speed > 0:           # standstill: static friction, of a sign the speed cannot tell
            still = np.abs(v) < self.min_speed          # NaN speeds stay in and are counted as non-finite
            self.n_standstill += int(still.sum())
            tau, v = tau[~still], v[~still]
        if self.compensation is not None:
            tau = self.compensation.apply(tau, v)
        coef = None if self.load is None else self.load.coefficients(v)
        self.channels["raw"].update(tau, coef)
        if self.weights is not None:
            w = self.weights(v)
            if self.center:
                located, located_coef = self._causally_centred(tau, coef)
            else:
                located, located_coef = tau, coef
            self.channels["weighted"].update(w * located, None if located_coef is None else w * located_coef)

    def update(self, cycle: CycleInput, context: Mapping[str, float] | None = None) -> FeatureOutput:
        """The feature step (:class:`~edge_monitor.features.base.Feature`): close the cycle and give the
        ``"kl"`` section, the quantities ``kl_raw``/``kl_weighted`` and the raw density for viewers. A
        partial cycle is discarded (its window lacks the cycle's start). The ``temperature`` of the
        context (the wear feature's ξ̂) updates the temperature compensation of the next cycles."""
        heating = self.heat.close(cycle.t)
        if self.compensation is not None:
            motor = cycle.motor_temperature
            self.compensation.observe((context or {}).get("temperature"),
                                      loose=motor is None or not math.isfinite(motor), heating=heating)
        if cycle.partial:
            self.discard_cycle()
            return FeatureOutput(section=dict(EMPTY_SECTION), values={q: math.nan for q in self.quantities})
        result = self.end_cycle(cycle.cycle, None if self.load is None else self.load.cycle_load(cycle))
        values = {"kl_raw": _nan_if_none(result.raw), "kl_weighted": _nan_if_none(result.weighted)}
        extras = {"density": result.density} if result.density is not None else {}
        section = result.to_section()
        if self.compensation is not None and self.compensation.current is not None:
            section["temperature"] = self.compensation.section()
        return FeatureOutput(section=section, values=values, reason=result.reason, extras=extras)

    def pause(self, seconds: float) -> None:
        """The joint stood still for ``seconds`` before its next samples: its lubricant cooled meanwhile."""
        self.heat.pause(seconds)
        if self.compensation is not None:
            self.compensation.cool(seconds)

    def discard_cycle(self) -> None:
        """Drop the open window without evaluating or learning (partial or duplicate cycles)."""
        for ch in self.channels.values():
            ch.new_window()
        self._new_window()

    def end_cycle(self, cycle: int, load: tuple[float, str] | None = None) -> KLResult:
        """Close the cycle: density, KL distances (or learning step, or a reason) and a new window.
        ``load``: the cycle's |load torque| and its source (needed when the load is compensated)."""
        try:
            return self._evaluate(int(cycle), load)
        finally:
            for ch in self.channels.values():
                ch.new_window()
            self._new_window()

    def _outside(self) -> dict[str, dict[str, int]]:
        return {name: ch.counts() for name, ch in self.channels.items()}

    def _unusable(self) -> str | None:
        """Why this cycle cannot give a KL value, or None if it can."""
        if self.n_window == 0:
            return "empty window: no samples" + (" in the production segment" if self.window == "production" else "")
        if self.n_standstill == self.n_window:
            return f"joint too slow: all {self.n_window} samples slower than kl.min_speed = {self.min_speed:g} rad/s"
        counts = [ch.n_samples for ch in self.channels.values()]
        if min(counts) < self.min_samples:
            nonfinite = max(ch.n_nonfinite for ch in self.channels.values())
            extra = f" ({nonfinite} non-finite skipped)" if nonfinite else ""
            return f"cycle too short: {min(counts)} samples < {self.min_samples}{extra}"
        for name, ch in self.channels.items():
            if not ch.has_spread():
                return "constant data" if name == "raw" else f"constant data ({name})"
        return None

    def _evaluate(self, cycle: int, load: tuple[float, str] | None = None) -> KLResult:
        result = KLResult(cycle=cycle, n_samples=self.channels["raw"].n_samples, outside=self._outside(),
                          standstill=self.n_standstill)
        reason = self._unusable()
        eps, result.load = (0.0, None) if reason is not None or self.load is None else self.load.change(load)
        if reason is None and eps is None:
            reason = "load unknown: no plateau measured in both directions and no load estimate"
        if reason is not None or eps is None:
            result.reason = reason
            log.info("cycle %d: no KL value: %s", cycle, reason)
            return result
        for ch in self.channels.values():
            if not ch.grid_fixed:
                ch.fix_grid(eps)
        windows = {name: ch.window_kde(eps) for name, ch in self.channels.items()}
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
            "heat": self.heat.state_dict(),
            "n_learned": self.n_learned, "n_window": self.n_window, "n_standstill": self.n_standstill,
            "torque_sum": self.torque_sum, "torque_count": self.torque_count,
            "coefficient_sum": self.coefficient_sum,
            "load_compensation": None if self.load is None else self.load.state_dict(),
            "channels": {name: ch.state_dict() for name, ch in self.channels.items()},
            "modes": {name: d.tolist() for name, d in self.modes.items()},
        }

    def fingerprint(self) -> dict[str, Any]:
        """What the learned densities depend on: the config, and the friction model that compensates
        temperature (when it does)."""
        out = self.config.fingerprint()
        if (self.compensation is not None or self.load is not None) and self.params is not None:
            out["friction"] = self.params.to_dict()
        return out

    @classmethod
    def from_state(cls, config: KLConfig, state: dict[str, Any], params: FrictionParams | None = None) -> "KLMonitor":
        """Restore a monitor learned with ``config``; :class:`StateMismatch` if it was learned with another."""
        mon = cls(config, params)
        check_learned_with("kl", state, mon.fingerprint())
        if mon.compensation is not None and isinstance(state.get("compensation"), dict):
            mon.compensation.load_state(state["compensation"])
        mon.heat = CycleHeat.from_state(state.get("heat"))
        mon.n_learned = int(state["n_learned"])
        mon.n_window = int(state["n_window"])
        mon.n_standstill = int(state.get("n_standstill", 0))
        mon.torque_sum = float(state.get("torque_sum", 0.0))
        mon.torque_count = int(state.get("torque_count", 0))
        mon.coefficient_sum = float(state.get("coefficient_sum", 0.0))
        if mon.load is not None:
            mon.load.load_state(state.get("load_compensation"))
        mon.channels = {name: KLChannel.from_state(mon.n_grid, mon._centred_by_mean(name), state["channels"][name],
                                                   mon._coefficient_bound(name))
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
