"""Per-quantity sequential detector of the agent: learning phase, threshold calibration, then window-limited GLR.

One detector watches one per-cycle quantity (wear estimate, log ``kl.raw``, log ``kl.weighted``) or a vector of
them (``dim`` > 1). It collects ``n_nominal`` finite values, fits the nominal density (docs/ALGORITHMS.md §5),
calibrates its alarm threshold for the mean run length to false alarm ``arl0`` by simulation
(:mod:`edge_monitor.stats.calibration`; with ``pf``, an expert option, the asymptotic ½·χ²_d quantile at 1 − Pf
of one test), then runs :class:`~edge_monitor.stats.glr.WindowedGLR` on every new value. The first crossing
latches an alarm until :meth:`SequentialDetector.reset` (a declared maintenance, which restarts learning).
Non-finite values are skipped and counted, never touch the state. A calibration may run in another process
(live agent): until its threshold arrives the detector monitors without deciding; a statistic that crossed
meanwhile raises the alarm when the threshold comes.

Two stages: the nominal learned right after commissioning is the *warm-up* nominal, calibrated at
``calibrate_at``. Once the joint's temperature has settled (:meth:`SequentialDetector.begin_steady`) the
detector learns its nominal again from the next ``steady_nominal`` values, deciding with the warm-up threshold
meanwhile, and calibrates that *steady* nominal at ``steady_at`` (docs/DETECTION.md).
"""

from __future__ import annotations

import logging
import math
from dataclasses import replace
from typing import Any, Protocol, Sequence

import numpy as np

from edge_monitor.errors import check_learned_with
from edge_monitor.records import Decision
from edge_monitor.stats.calibration import Calibration, CalibrationError, CalibrationJob
from edge_monitor.stats.calibrators import InlineCalibrator, Pending
from edge_monitor.stats.densities import DensityError, GaussianMixture, fit_density
from edge_monitor.stats.detector_config import (  # noqa: F401  (re-exported: the detector's settings live there)
    DEFAULT_MODE,
    DEFAULT_NOMINAL,
    DEFAULT_STEADY_NOMINAL,
    DEFAULT_WINDOW,
    MAX_NOMINAL,
    DetectorConfig,
    DetectorConfigError,
    learned_part,
)
from edge_monitor.stats.detector_state import recalibrated, saved_steady_values, saved_target, saved_transform
from edge_monitor.stats.glr import GLRError, WindowedGLR, threshold_from_pf
from edge_monitor.stats.glr_batch import clip_range, null_box
from edge_monitor.stats.normalising_transform import TransformError, YeoJohnson

log = logging.getLogger(__name__)


class Calibrator(Protocol):
    """Runs calibrations (:class:`~edge_monitor.stats.calibration.InlineCalibrator` or a process pool)."""

    def submit(self, job: CalibrationJob) -> Pending: ...


class SequentialDetector:
    """Learning (``n_nominal`` finite values) → threshold calibration → monitoring with a window-limited
    GLR (see the module docstring).

    Values are the per-cycle quantity in its own units; ``cycle`` is the agent's cycle number and is
    only used to report ``change_cycle``. If the nominal values are constant (no density can be
    fitted), the detector keeps learning on a sliding window of the latest ``n_nominal`` values and
    says so in ``reason``; it starts as soon as the window shows any spread.
    """

    def __init__(self, config: DetectorConfig | None = None, calibrator: Calibrator | None = None) -> None:
        self.config = config = config or DetectorConfig()
        self.calibrator: Calibrator = calibrator or InlineCalibrator()
        self.dim, self.n_nominal = config.dim, config.n_nominal
        self.window, self.gamma0, self.rho, self.mode = config.window, config.gamma0, config.rho, config.mode
        self.skipped_nonfinite = 0
        self.skipped_bad_shape = 0
        self.resets = 0
        self.fits = 0                      # nominals fitted so far (warm-up, steady, after resets)
        self.arl0 = float(config.arl0)     # the target [cycles]; :meth:`retarget` changes it
        self._clear()

    def _clear(self) -> None:
        self._nominal: list[list[float]] = []
        self.glr: WindowedGLR | None = None      # the GLR in use (None while learning)
        self._cycles: list[int | None] = [None] * self.window
        self._latched: dict[str, Any] | None = None
        self._learning_note = ""
        self.calibration: Calibration | None = None
        self._job: CalibrationJob | None = None
        self.calibrated_job: CalibrationJob | None = None      # the job of the threshold in use (for :meth:`retarget`)
        self._pending: Pending | None = None
        self._waiting: dict[str, Any] = {"statistic": 0.0}  # the largest statistic while calibrating, and when
        self.stage = "warm-up"             # "warm-up" | "steady" (see the module docstring)
        self._steady_values: list[list[float]] | None = None    # the steady nominal being learned
        self.transform: YeoJohnson | None = None    # applied to every value before the GLR (steady stage)

    @property
    def state(self) -> str:
        return "learning" if self.glr is None else "monitoring"

    @property
    def collecting(self) -> bool:
        """Whether the values fed now go into a nominal being learned (warm-up or steady)."""
        return self.glr is None or (self._steady_values is not None and self._latched is None)

    @property
    def collecting_steady(self) -> bool:
        """Whether the values fed now go into the steady nominal (learned once the joint has settled)."""
        return self.collecting and (self.stage == "steady" or self._steady_values is not None)

    @property
    def alarmed(self) -> bool:
        """Whether an alarm is latched (until :meth:`reset`)."""
        return self._latched is not None

    @property
    def crossing(self) -> dict[str, Any] | None:
        """The latched alarm's crossing: its ``statistic``, ``cycle`` and ``change_cycle`` (None without one)."""
        return None if self._latched is None else dict(self._latched)

    @property
    def density(self) -> GaussianMixture | None:
        return None if self.glr is None else self.glr.density

    @property
    def threshold(self) -> float | None:
        """The alarm threshold [nats] once known (learned and calibrated)."""
        if self.glr is None or not math.isfinite(self.glr.threshold):
            return None
        return self.glr.threshold

    def calibration_record(self) -> dict[str, Any] | None:
        """How the threshold is set, for every decision: the ARL0 target and the method, or the Pf."""
        if self.config.pf is not None:
            return {"method": "asymptotic", "pf": self.config.pf}
        out: dict[str, Any] = {"arl0": self.arl0, "at": self._calibration["at"], "stage": self.stage}
        if self.calibration is not None:       # the threshold in use (a re-derived one may be on its way)
            out.update(arl0=self.calibration.arl0, at=self.calibration.at, method=self.calibration.method)
            if self.calibration.h_se is not None:
                out["h_se"] = self.calibration.h_se
        elif self.glr is not None:
            out["method"] = "pending"
        return out

    @property
    def _density_kind(self) -> str:
        return self.config.steady_density if self.stage == "steady" else self.config.density

    @property
    def _n_learn(self) -> int:
        return self.config.steady_nominal if self.stage == "steady" else self.n_nominal

    @property
    def _calibration(self) -> dict[str, Any]:
        """Where the calibration of the current stage simulates the detector (the point, the drift after
        learning in σ units, the slow wander) and, once steady, what it simulates from."""
        out = self.config.calibration(self.stage)
        return {**out, "simulate_from": self.config.steady_simulate_from} if self.stage == "steady" else out

    def begin_steady(self) -> None:
        """The joint's temperature has settled: learn the nominal again from the next ``steady_nominal``
        values and calibrate it at ``steady_at``. No-op once steady, while relearning, or with an alarm."""
        if self.stage == "steady" or self._steady_values is not None or self._latched is not None:
            return
        if self.glr is None:                  # still learning: start over with settled values only
            self._nominal.clear()
            self.stage, self._learning_note = "steady", ""
        else:
            self._steady_values = []

    def cancel_steady(self) -> None:
        """The joint warms again: drop the steady values collected so far (a steady nominal stays)."""
        self._steady_values = None

    def update(self, value: float | Sequence[float], cycle: int, slack: Sequence[float] | None = None) -> Decision:
        """Fold in one per-cycle value (scalar or ``dim``-vector) and return the decision; a monitoring detector
        tests the value less ``slack`` [nominal std per axis], a healthy drift its nominal does not describe."""
        self._collect_calibration(cycle)
        vec, problem = self._as_vector(value)
        if vec is None:
            return replace(self._current(), reason=problem)
        if self.glr is None:
            return self._learn(vec, cycle)
        return self._monitor(vec, cycle, slack)

    def collect(self, value: float | Sequence[float], cycle: int, reason: str) -> Decision:
        """A cycle on which the detector holds (does not decide, for ``reason``): its value still goes into
        the steady nominal being collected, if any, and completes it like :meth:`update`."""
        self._collect_calibration(cycle)
        if self.glr is None or self._steady_values is None or self._latched is not None:
            return self.idle(reason)
        vec, problem = self._as_vector(value)
        if vec is None:
            return self.idle(f"{reason}; {problem}")
        fitted = self._add_steady_value(vec, cycle)
        return self.idle(reason) if fitted is None else fitted

    def reset(self) -> None:
        """Declared maintenance: clear the alarm and the nominal model, learn again."""
        self._clear()
        self.resets += 1

    def acknowledge(self) -> None:
        """The latched alarm was judged false: restart the statistic on the same nominal and threshold (no
        relearning, unlike :meth:`reset`); steady values collected before it are kept (none while latched)."""
        if self.glr is not None:
            self.glr.restart()
        self._latched = None
        self._cycles = [None] * self.window

    def retarget(self, arl0: float) -> bool:
        """Re-derive the threshold for another mean run length ``arl0`` [cycles] on the same nominal (the
        budget's cycle rate changed); the current threshold decides until the new one arrives. Whether
        a calibration was started (a learning detector only takes the new target)."""
        arl0 = float(arl0)
        if self.config.pf is not None or arl0 == self.arl0:
            return False
        self.arl0 = arl0
        job = self._job or self.calibrated_job
        if self.glr is None or job is None:
            return False
        self._job, self._waiting = replace(job, arl0=arl0), {"statistic": 0.0}
        self._pending = self.calibrator.submit(self._job)
        return True

    def counters(self) -> dict[str, int]:
        return {"skipped_nonfinite": self.skipped_nonfinite, "skipped_bad_shape": self.skipped_bad_shape,
                "resets": self.resets, "fits": self.fits}

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
        if len(self._nominal) > self._n_learn:
            del self._nominal[0]
        if len(self._nominal) < self._n_learn:
            return Decision("learning", reason=self._learning_reason(), calibration=self.calibration_record())
        return self._fit(cycle)

    def _fit(self, cycle: int) -> Decision:
        """Fit the nominal density of ``self._nominal``, start the GLR and its calibration."""
        try:
            nominal = self.config.learning_values(self.stage, np.asarray(self._nominal))
            if self.stage == "steady" and self.config.steady_transform == "yeo-johnson" and any(
                    self.config.transform_axes or (True,)):
                self.transform = YeoJohnson.fit(nominal, self.config.transform_axes)
                nominal = self.transform.apply(nominal)
            density = fit_density(nominal, self._density_kind)
            threshold = threshold_from_pf(self.config.pf, self.dim) if self.config.pf is not None else math.inf
            self.glr = WindowedGLR(density, self.window, 0.5, self.gamma0, self.rho,
                                    "exact" if self.mode == "exact" else "recursive", threshold=threshold,
                                    null_box=null_box(nominal, self.config.direction, self.config.allowance),
                                    clip=clip_range(nominal, self.config.clip_sigma))
        except (DensityError, GLRError, TransformError) as exc:
            self.transform = None
            self._learning_note = f"nominal data unusable, still learning: {exc}"
            log.info("detector stays in learning: %s", exc)
            return Decision("learning", reason=self._learning_note, calibration=self.calibration_record())
        if self.config.pf is None:
            self._job = CalibrationJob(tuple(map(tuple, nominal.tolist())), self._density_kind, self.window,
                                       self.arl0, self.gamma0, self.rho, self.mode, self.config.budget,
                                       self.config.direction, float(self.config.allowance),
                                       float(self.config.clip_sigma), **self._calibration)
            self._pending = self.calibrator.submit(self._job)
        self._nominal.clear()
        self._learning_note = ""
        self.fits += 1
        self._collect_calibration(cycle)
        log.info("%s nominal %s density learned (%d components); monitoring from cycle %s",
                 self.stage, self._density_kind, density.n_components, cycle)
        return Decision("monitoring", threshold=self.threshold, alarm=self.alarmed,
                        reason=f"nominal density learned ({density.n_components} components)",
                        calibration=self.calibration_record())

    def _collect_calibration(self, cycle: int) -> None:
        """Adopt a finished calibration; an alarm if the statistic already exceeded its threshold."""
        if self._pending is None or self.glr is None:
            return
        try:
            calibration = self._pending.result()
        except (CalibrationError, DensityError, ValueError) as exc:    # degenerate nominal: asymptotic fallback
            log.warning("threshold calibration failed (%s); using the asymptotic threshold for Pf = 1e-9", exc)
            calibration = Calibration(threshold_from_pf(1e-9, self.dim), self.arl0, "fallback",
                                      0, 0, 0, None, 0.0, self._calibration["at"])
        if calibration is None:
            return
        self.calibration, self._pending, self._job, self.calibrated_job = calibration, None, None, self._job
        self.glr.threshold = calibration.threshold
        log.info("threshold %.3f for ARL0 %.0f cycles (%s, %d × %d simulated cycles, %.1f s CPU)",
                 calibration.threshold, calibration.arl0, calibration.method, calibration.draws,
                 calibration.steps, calibration.cpu_s)
        if self._waiting["statistic"] >= calibration.threshold and self._latched is None:    # crossed meanwhile
            self._latched = {"cycle": int(cycle), "change_cycle": None, **self._waiting}

    def _learning_reason(self) -> str:
        return self._learning_note or f"learning {len(self._nominal)}/{self._n_learn}"

    # ------------------------------------------------------------------ monitoring
    def _monitor(self, vec: np.ndarray, cycle: int, slack: Sequence[float] | None = None) -> Decision:
        assert self.glr is not None
        fitted = self._add_steady_value(vec, cycle)
        if fitted is not None:
            return fitted
        if self.transform is not None:
            vec = self.transform.apply(vec)
            if not np.all(np.isfinite(vec)):       # a finite value too large for the transform
                self.skipped_nonfinite += 1
                return replace(self._current(), reason="value skipped: too large to transform")
        vec = vec if slack is None else vec - np.asarray(slack, dtype=float) * self.glr.density.spread
        result = self.glr.update(vec)
        self._cycles[result.index % self.window] = int(cycle)
        change_cycle = self._cycles[result.change_index % self.window]
        delta = self._shift_in_units(result.delta)
        if self.threshold is None:
            if result.statistic > self._waiting["statistic"]:
                self._waiting = {"statistic": result.statistic, "cycle": int(cycle), "change_cycle": change_cycle}
            return Decision("monitoring", result.statistic, None, False, change_cycle, delta, None,
                            "calibrating the threshold", self.calibration_record())
        if result.alarm and self._latched is None:
            self._latched = {"cycle": int(cycle), "change_cycle": change_cycle, "statistic": result.statistic}
            log.warning("alarm at cycle %s: statistic %.3g ≥ %.3g, change since cycle %s",
                        cycle, result.statistic, result.threshold, change_cycle)
        reason = "alarm latched until reset()" if self._latched else "monitoring"
        return Decision("monitoring", result.statistic, result.threshold, self._latched is not None,
                        change_cycle, delta, result.miss_probability, reason, self.calibration_record())

    def _shift_in_units(self, delta: Sequence[float]) -> tuple[float, ...]:
        """The GLR's shift estimate in the units the detector is fed (back through the transform)."""
        if self.transform is None or self.glr is None:
            return tuple(float(v) for v in delta)
        return self.transform.shift_in_units(self.glr.density.mean, delta)

    def _add_steady_value(self, vec: np.ndarray, cycle: int) -> Decision | None:
        """Add ``vec`` to the steady nominal being collected (none while an alarm is latched); the fit's
        decision once the nominal is complete, else ``None``."""
        if self._steady_values is None or self._latched is not None:
            return None
        self._steady_values.append(vec.tolist())
        return self._start_steady(cycle) if len(self._steady_values) >= self.config.steady_nominal else None

    def _start_steady(self, cycle: int) -> Decision:
        """Replace the warm-up nominal and threshold by the steady nominal just learned."""
        nominal = self._steady_values or []
        self._clear()
        self._nominal, self.stage = nominal, "steady"
        return self._fit(cycle)

    def _current(self) -> Decision:
        """The decision of a cycle whose value did not enter the detector (state unchanged)."""
        if self.glr is None:
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
                "glr": None if self.glr is None else self.glr.state_dict(),
                "calibration": None if self.calibration is None else self.calibration.to_dict(),
                "calibration_job": None if self._job is None else self._job.to_dict(), "arl0": self.arl0,
                "calibrated_job": None if self.calibrated_job is None else self.calibrated_job.to_dict(),
                "waiting": dict(self._waiting),
                "cycles": list(self._cycles), "latched": None if self._latched is None else dict(self._latched),
                "learning_note": self._learning_note, "counters": self.counters(), "stage": self.stage,
                "steady_values": None if self._steady_values is None else [list(v) for v in self._steady_values],
                "transform": None if self.transform is None else self.transform.state_dict()}

    @classmethod
    def from_state(cls, config: DetectorConfig, state: dict[str, Any],
                   calibrator: Calibrator | None = None) -> "SequentialDetector":
        """Restore a detector learned with ``config``; :class:`StateMismatch` if it was learned with
        another. A calibration that was under way is started again (it is deterministic)."""
        saved = state.get("config")          # states saved with the target or the calibration settings in
        if isinstance(saved, dict):          # it: those are not learned, they are re-derived (below)
            state = {**state, "config": learned_part(saved)}
        check_learned_with("detector", state, config.fingerprint())
        det = cls(config, calibrator)
        det.arl0 = saved_target(state.get("arl0", config.arl0))
        det._nominal = [list(map(float, v)) for v in state["nominal"]]
        det.glr = None if state["glr"] is None else WindowedGLR.from_state(state["glr"])
        if state.get("calibration") is not None:
            det.calibration = Calibration.from_dict(state["calibration"])
        if state.get("calibrated_job") is not None and det.glr is not None:
            det.calibrated_job = CalibrationJob.from_dict(state["calibrated_job"])
        if state.get("calibration_job") is not None and det.glr is not None:
            det._job = CalibrationJob.from_dict(state["calibration_job"])
        det._waiting = dict(state.get("waiting") or {"statistic": float(state.get("waiting_max", 0.0))})
        det._cycles = [None if c is None else int(c) for c in state["cycles"]]
        det._latched = None if state["latched"] is None else dict(state["latched"])
        det._learning_note = state.get("learning_note", "")
        det.stage = "steady" if state.get("stage") == "steady" else "warm-up"
        job = det._job or det.calibrated_job
        if config.pf is None and job is not None and recalibrated(job, det._calibration):   # calibrated elsewhere
            det._job = replace(job, **det._calibration)      # than the config says: re-derived; a threshold in
            det._waiting = det._waiting if det.calibration is None else {"statistic": 0.0}   # use decides meanwhile
        if det._job is not None:                    # (the saved threshold decides until then)
            det._pending = det.calibrator.submit(det._job)
        det._steady_values = saved_steady_values(state.get("steady_values"), det)
        det.transform = saved_transform(state.get("transform"), det)
        counters = state.get("counters", {})
        det.skipped_nonfinite = int(counters.get("skipped_nonfinite", 0))
        det.skipped_bad_shape = int(counters.get("skipped_bad_shape", 0))
        det.resets = int(counters.get("resets", 0))
        det.fits = int(counters.get("fits", 0))
        return det
