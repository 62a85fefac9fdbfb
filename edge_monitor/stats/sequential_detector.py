"""Per-quantity sequential detector of the agent: learning phase, threshold calibration, then
window-limited GLR.

One detector watches one per-cycle quantity (wear estimate, log ``kl.raw``, log ``kl.weighted``) or a
vector of them (``dim`` > 1). It collects ``n_nominal`` finite values, fits the nominal density
(docs/ALGORITHMS.md §5), calibrates its alarm threshold for the stated mean run length to false alarm
``arl0`` by simulating its own statistic under its own learned nominal model
(:mod:`edge_monitor.stats.calibration`), and then runs :class:`~edge_monitor.stats.glr.WindowedGLR`
on every new value. With ``pf`` set instead (an expert option) the threshold is the asymptotic
½·χ²_d quantile at 1 − Pf of one test. An alarm is latched after the first threshold crossing until
:meth:`SequentialDetector.reset` (a declared maintenance), which also restarts learning. Non-finite
values are skipped and counted and never touch the state.

A calibration may run in another process (live agent): until its threshold arrives the detector
monitors without deciding ("calibrating"); the first decision with the threshold also accounts for the
statistics of those cycles.
"""

from __future__ import annotations

import logging
import math
from dataclasses import asdict, dataclass, replace
from typing import Any, Protocol, Sequence

import numpy as np

from edge_monitor.errors import ConfigError, check_learned_with, require
from edge_monitor.records import Decision
from edge_monitor.stats.bias_em import BiasEMError, check_gain
from edge_monitor.stats.calibration import (
    CALIBRATE_AT,
    DEFAULT_ARL0,
    MAX_ARL0,
    MAX_DRIFT,
    MIN_EVENTS,
    Calibration,
    CalibrationBudget,
    CalibrationError,
    CalibrationJob,
    InlineCalibrator,
    Pending,
)
from edge_monitor.stats.densities import DENSITY_KINDS, DensityError, GaussianMixture, fit_density, min_points
from edge_monitor.stats.glr import MAX_WINDOW, GLRError, WindowedGLR, check_pf, threshold_from_pf
from edge_monitor.stats.glr_batch import DIRECTIONS, clip_range, null_box

log = logging.getLogger(__name__)

#: Candidate change times kept by the agent's detectors [cycles].
DEFAULT_WINDOW = 100
#: Learning phase length [cycles] (docs/ALGORITHMS.md §6: 50 … 70).
DEFAULT_NOMINAL = 60
#: Longest learning phase [cycles]: the nominal values are kept until the density is fitted.
MAX_NOMINAL = 10_000
#: GLR numerator mode. "recursive" is the O(W·K) variant (≈ 0.2 ms per update at W = 100);
#: "exact" is O(W²·K). The calibration simulates whichever the detector runs.
DEFAULT_MODE = "recursive"


class Calibrator(Protocol):
    """Runs calibrations (:class:`~edge_monitor.stats.calibration.InlineCalibrator` or a process pool)."""

    def submit(self, job: CalibrationJob) -> Pending: ...


class DetectorConfigError(ConfigError):
    """Invalid detector setting (names the parameter and the valid range)."""


@dataclass(frozen=True)
class DetectorConfig:
    """Settings of one sequential detector, validated once, here.

    ``arl0``: mean run length to false alarm [cycles] the threshold is calibrated for; ``pf``: instead,
    the per-test false-alarm probability of the asymptotic threshold (expert option; then ``arl0`` is
    not used). ``calibration_draws``/``calibration_steps``: simulation budget of the calibration;
    ``calibrate_at``, ``drift_mean``/``drift_sd`` [σ of the nominal values, one per dimension]: which
    healthy data the target is for (:func:`~edge_monitor.stats.calibration.stream_shifts`).
    """

    dim: int = 1
    n_nominal: int = DEFAULT_NOMINAL
    density: str = "gce"
    window: int = DEFAULT_WINDOW
    gamma0: float = 0.6
    rho: float = 1.0
    mode: str = DEFAULT_MODE
    arl0: float = DEFAULT_ARL0
    pf: float | None = None
    direction: str = "both"
    allowance: float = 0.0
    clip_sigma: float = 0.0
    calibration_draws: int = CalibrationBudget().draws
    calibration_steps: int = CalibrationBudget().max_steps
    calibrate_at: str = "boundary"
    drift_mean: tuple[float, ...] = ()
    drift_sd: tuple[float, ...] = ()

    def __post_init__(self) -> None:
        try:
            require(isinstance(self.dim, int) and 1 <= self.dim <= 16, "dim", f"must be 1 … 16, got {self.dim!r}")
            require(self.density in DENSITY_KINDS, "density", f"{self.density!r}; choose one of {DENSITY_KINDS}")
            need = min_points(self.density, self.dim)
            require(isinstance(self.n_nominal, int) and need <= self.n_nominal <= MAX_NOMINAL, "n_nominal",
                    f"{self.n_nominal!r} cycles: the {self.density!r} density in dimension {self.dim} needs "
                    f"{need} … {MAX_NOMINAL} (default {DEFAULT_NOMINAL})")
            require(isinstance(self.window, int) and 1 <= self.window <= MAX_WINDOW, "window",
                    f"must be 1 … {MAX_WINDOW} cycles, got {self.window!r} (default {DEFAULT_WINDOW})")
            require(self.mode in ("exact", "recursive"), "mode", f"must be 'exact' or 'recursive', got {self.mode!r}")
            require(isinstance(self.arl0, (int, float)) and 10 <= self.arl0 <= MAX_ARL0, "arl0",
                    f"mean run length to false alarm must be 10 … {MAX_ARL0:g} cycles, got {self.arl0!r}")
            require(self.direction in DIRECTIONS, "direction", f"{self.direction!r}; choose one of {DIRECTIONS}")
            require(isinstance(self.allowance, (int, float)) and 0 <= self.allowance <= 5, "allowance",
                    f"must be 0 … 5 standard deviations of the nominal values, got {self.allowance!r}")
            require(isinstance(self.clip_sigma, (int, float)) and (self.clip_sigma == 0 or 1 <= self.clip_sigma <= 20),
                    "clip_sigma", f"must be 0 (off) or 1 … 20 standard deviations, got {self.clip_sigma!r}")
            require(isinstance(self.calibration_draws, int) and MIN_EVENTS <= self.calibration_draws <= 4096,
                    "calibration_draws", f"must be {MIN_EVENTS} … 4096 (a threshold needs {MIN_EVENTS} simulated "
                    f"alarms), got {self.calibration_draws!r}")
            require(isinstance(self.calibration_steps, int) and 200 <= self.calibration_steps <= 1_000_000,
                    "calibration_steps", f"must be 200 … 1000000, got {self.calibration_steps!r}")
            require(self.calibrate_at in CALIBRATE_AT, "calibrate_at",
                    f"{self.calibrate_at!r}; choose one of {CALIBRATE_AT}")
            if self.calibrate_at == "healthy_drift":
                bounds = (("drift_mean", self.drift_mean, -MAX_DRIFT), ("drift_sd", self.drift_sd, 0.0))
                for name, values, low in bounds:
                    require(len(values) == self.dim and all(isinstance(v, (int, float)) and low <= v <= MAX_DRIFT
                                                            for v in values), name,
                            f"needs {self.dim} value(s) in {low:g} … {MAX_DRIFT:g} standard deviations, "
                            f"got {values!r}")
        except ConfigError as exc:
            raise DetectorConfigError(str(exc)) from None
        for name, gamma0, rho in (("gamma0", self.gamma0, 0.75), ("rho", 0.5, self.rho)):
            try:
                check_gain(gamma0, rho)
            except BiasEMError as exc:
                raise DetectorConfigError(f"{name}: {exc}") from None
        if self.pf is not None:
            try:
                check_pf(self.pf)
            except GLRError as exc:
                raise DetectorConfigError(f"pf: {exc}") from None

    def fingerprint(self) -> dict[str, Any]:
        out = {**asdict(self), "drift_mean": list(self.drift_mean), "drift_sd": list(self.drift_sd)}
        if self.calibrate_at == "boundary" and not (self.drift_mean or self.drift_sd):
            for key in ("calibrate_at", "drift_mean", "drift_sd"):     # the default: states saved before
                del out[key]                                           # these settings existed still match
        return out

    @property
    def budget(self) -> CalibrationBudget:
        return CalibrationBudget(draws=self.calibration_draws, max_steps=self.calibration_steps)


class SequentialDetector:
    """Learning (``n_nominal`` finite values) → threshold calibration → monitoring with a window-limited
    GLR (see the module docstring).

    Values are the per-cycle quantity in its own units; ``cycle`` is the agent's cycle number and is
    only used to report ``change_cycle``. If the nominal values are constant (no density can be
    fitted), the detector keeps learning on a sliding window of the latest ``n_nominal`` values and
    says so in ``reason``; it starts as soon as the window shows any spread.
    """

    def __init__(self, config: DetectorConfig = DetectorConfig(), calibrator: Calibrator | None = None) -> None:
        self.config = config
        self.calibrator: Calibrator = calibrator or InlineCalibrator()
        self.dim, self.n_nominal, self.density_kind = config.dim, config.n_nominal, config.density
        self.window, self.gamma0, self.rho, self.mode = config.window, config.gamma0, config.rho, config.mode
        self.skipped_nonfinite = 0
        self.skipped_bad_shape = 0
        self.resets = 0
        self._clear()

    def _clear(self) -> None:
        self._nominal: list[list[float]] = []
        self._glr: WindowedGLR | None = None
        self._cycles: list[int | None] = [None] * self.window
        self._latched: dict[str, Any] | None = None
        self._learning_note = ""
        self.calibration: Calibration | None = None
        self._job: CalibrationJob | None = None
        self._pending: Pending | None = None
        self._waiting_max = 0.0            # largest statistic while the calibration was under way

    @property
    def state(self) -> str:
        return "learning" if self._glr is None else "monitoring"

    @property
    def alarmed(self) -> bool:
        """Whether an alarm is latched (until :meth:`reset`)."""
        return self._latched is not None

    @property
    def density(self) -> GaussianMixture | None:
        return None if self._glr is None else self._glr.density

    @property
    def threshold(self) -> float | None:
        """The alarm threshold [nats] once known (learned and calibrated)."""
        if self._glr is None or not math.isfinite(self._glr.threshold):
            return None
        return self._glr.threshold

    def calibration_record(self) -> dict[str, Any] | None:
        """How the threshold is set, for every decision: the ARL0 target and the method, or the Pf."""
        if self.config.pf is not None:
            return {"method": "asymptotic", "pf": self.config.pf}
        out: dict[str, Any] = {"arl0": self.config.arl0, "at": self.config.calibrate_at}
        if self.calibration is not None:
            out["method"] = self.calibration.method
        elif self._glr is not None:
            out["method"] = "pending"
        return out

    def update(self, value: float | Sequence[float], cycle: int) -> Decision:
        """Fold in one per-cycle value (scalar or ``dim``-vector) and return the decision."""
        self._collect_calibration(cycle)
        vec, problem = self._as_vector(value)
        if vec is None:
            return replace(self._current(), reason=problem)
        if self._glr is None:
            return self._learn(vec, cycle)
        return self._monitor(vec, cycle)

    def reset(self) -> None:
        """Declared maintenance: clear the alarm and the nominal model, learn again."""
        self._clear()
        self.resets += 1

    def counters(self) -> dict[str, int]:
        return {"skipped_nonfinite": self.skipped_nonfinite, "skipped_bad_shape": self.skipped_bad_shape,
                "resets": self.resets}

    def _as_vector(self, value: float | Sequence[float]) -> tuple[np.ndarray | None, str]:
        try:
            vec = np.asarray(value, dtype=float).ravel()
        except (TypeError, ValueError):
            vec = None
        if vec is None or vec.size != self.dim:
            self.skipped_bad_shape += 1
            return None, f"value skipped: expected {self.dim} number(s), got {value!r}"
        if not np.all(np.isfinite(vec)):
            self.skipped_nonfinite += 1
            return None, "non-finite value skipped"
        return vec, ""

    # ------------------------------------------------------------------ learning and calibration
    def _learn(self, vec: np.ndarray, cycle: int) -> Decision:
        self._nominal.append(vec.tolist())
        if len(self._nominal) > self.n_nominal:
            del self._nominal[0]
        if len(self._nominal) < self.n_nominal:
            return Decision("learning", reason=self._learning_reason(), calibration=self.calibration_record())
        try:
            nominal = np.asarray(self._nominal)
            density = fit_density(nominal, self.density_kind)
            threshold = threshold_from_pf(self.config.pf, self.dim) if self.config.pf is not None else math.inf
            self._glr = WindowedGLR(density, self.window, 0.5, self.gamma0, self.rho,
                                    "exact" if self.mode == "exact" else "recursive", threshold=threshold,
                                    null_box=null_box(nominal, self.config.direction, self.config.allowance),
                                    clip=clip_range(nominal, self.config.clip_sigma))
        except (DensityError, GLRError) as exc:
            self._learning_note = f"nominal data unusable, still learning: {exc}"
            log.info("detector stays in learning: %s", exc)
            return Decision("learning", reason=self._learning_note, calibration=self.calibration_record())
        if self.config.pf is None:
            self._job = CalibrationJob(tuple(tuple(v) for v in self._nominal), self.density_kind, self.window,
                                       float(self.config.arl0), self.gamma0, self.rho, self.mode, self.config.budget,
                                       self.config.direction, float(self.config.allowance),
                                       float(self.config.clip_sigma), self.config.calibrate_at,
                                       tuple(self.config.drift_mean), tuple(self.config.drift_sd))
            self._pending = self.calibrator.submit(self._job)
        self._nominal.clear()
        self._learning_note = ""
        self._collect_calibration(cycle)
        log.info("nominal %s density learned (%d components); monitoring from cycle %s",
                 self.density_kind, density.n_components, cycle)
        return Decision("monitoring", threshold=self.threshold, alarm=self.alarmed,
                        reason=f"nominal density learned ({density.n_components} components)",
                        calibration=self.calibration_record())

    def _collect_calibration(self, cycle: int) -> None:
        """Adopt a finished calibration; an alarm if the statistic already exceeded its threshold."""
        if self._pending is None or self._glr is None:
            return
        try:
            calibration = self._pending.result()
        except (CalibrationError, DensityError, ValueError) as exc:    # degenerate nominal: asymptotic fallback
            log.warning("threshold calibration failed (%s); using the asymptotic threshold for Pf = 1e-9", exc)
            calibration = Calibration(threshold_from_pf(1e-9, self.dim), float(self.config.arl0), "fallback",
                                      0, 0, 0, None, 0.0)
        if calibration is None:
            return
        self.calibration, self._pending, self._job = calibration, None, None
        self._glr.threshold = calibration.threshold
        log.info("threshold %.3f for ARL0 %.0f cycles (%s, %d × %d simulated cycles, %.1f s CPU)",
                 calibration.threshold, calibration.arl0, calibration.method, calibration.draws,
                 calibration.steps, calibration.cpu_s)
        if self._waiting_max >= calibration.threshold and self._latched is None:
            self._latched = {"cycle": int(cycle), "change_cycle": None, "statistic": self._waiting_max}

    def _learning_reason(self) -> str:
        return self._learning_note or f"learning {len(self._nominal)}/{self.n_nominal}"

    # ------------------------------------------------------------------ monitoring
    def _monitor(self, vec: np.ndarray, cycle: int) -> Decision:
        assert self._glr is not None
        result = self._glr.update(vec)
        self._cycles[result.index % self.window] = int(cycle)
        change_cycle = self._cycles[result.change_index % self.window]
        if self.threshold is None:
            self._waiting_max = max(self._waiting_max, result.statistic)
            return Decision("monitoring", result.statistic, None, False, change_cycle, tuple(result.delta), None,
                            "calibrating the threshold", self.calibration_record())
        if result.alarm and self._latched is None:
            self._latched = {"cycle": int(cycle), "change_cycle": change_cycle, "statistic": result.statistic}
            log.warning("alarm at cycle %s: statistic %.3g ≥ %.3g, change since cycle %s",
                        cycle, result.statistic, result.threshold, change_cycle)
        reason = "alarm latched until reset()" if self._latched else "monitoring"
        return Decision("monitoring", result.statistic, result.threshold, self._latched is not None,
                        change_cycle, tuple(result.delta), result.miss_probability, reason,
                        self.calibration_record())

    def _current(self) -> Decision:
        """The decision of a cycle whose value did not enter the detector (state unchanged)."""
        if self._glr is None:
            return Decision("learning", reason=self._learning_reason(), calibration=self.calibration_record())
        return Decision("monitoring", threshold=self.threshold, alarm=self.alarmed,
                        calibration=self.calibration_record())

    def idle(self, reason: str) -> Decision:
        """The decision of a cycle kept out of the detector (e.g. a partial cycle), with ``reason``."""
        return Decision(self.state, threshold=self.threshold, alarm=self.alarmed, reason=reason,
                        calibration=self.calibration_record())

    # ------------------------------------------------------------------ persistence
    def state_dict(self) -> dict[str, Any]:
        return {"config": self.config.fingerprint(),
                "nominal": [list(v) for v in self._nominal],
                "glr": None if self._glr is None else self._glr.state_dict(),
                "calibration": None if self.calibration is None else self.calibration.to_dict(),
                "calibration_job": None if self._job is None else self._job.to_dict(),
                "waiting_max": self._waiting_max,
                "cycles": list(self._cycles), "latched": None if self._latched is None else dict(self._latched),
                "learning_note": self._learning_note, "counters": self.counters()}

    @classmethod
    def from_state(cls, config: DetectorConfig, state: dict[str, Any],
                   calibrator: Calibrator | None = None) -> "SequentialDetector":
        """Restore a detector learned with ``config``; :class:`StateMismatch` if it was learned with
        another. A calibration that was under way is started again (it is deterministic)."""
        check_learned_with("detector", state, config.fingerprint())
        det = cls(config, calibrator)
        det._nominal = [list(map(float, v)) for v in state["nominal"]]
        det._glr = None if state["glr"] is None else WindowedGLR.from_state(state["glr"])
        if state.get("calibration") is not None:
            det.calibration = Calibration.from_dict(state["calibration"])
        if state.get("calibration_job") is not None and det._glr is not None:
            det._job = CalibrationJob.from_dict(state["calibration_job"])
            det._pending = det.calibrator.submit(det._job)
        det._waiting_max = float(state.get("waiting_max", 0.0))
        det._cycles = [None if c is None else int(c) for c in state["cycles"]]
        det._latched = None if state["latched"] is None else dict(state["latched"])
        det._learning_note = state.get("learning_note", "")
        counters = state.get("counters", {})
        det.skipped_nonfinite = int(counters.get("skipped_nonfinite", 0))
        det.skipped_bad_shape = int(counters.get("skipped_bad_shape", 0))
        det.resets = int(counters.get("resets", 0))
        return det
