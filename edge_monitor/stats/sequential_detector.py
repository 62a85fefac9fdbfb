"""Per-quantity sequential detector of the agent: learning phase, then window-limited GLR.

One detector watches one per-cycle quantity (wear estimate, ``kl.raw``, ``kl.weighted``) or a
vector of them (``dim`` > 1). It collects ``n_nominal`` finite values, fits the nominal density
(ALGORITHMS.md §5) and then runs :class:`~edge_monitor.stats.glr.WindowedGLR` on every new value. An alarm
is latched after the first threshold crossing until :meth:`SequentialDetector.reset` (a declared
maintenance), which also restarts learning. Non-finite values are skipped and counted and never
touch the state.

Default false-alarm probability: :data:`DEFAULT_PF` per test, chosen so that the measured run
length to false alarm (ARL0) of the windowed test is at least 10⁴ cycles for roughly Gaussian
per-cycle values (measured > 4·10⁴; tools/arl_study.py, docs/DETECTION.md). For skewed, long-tailed
values (e.g. a raw KL distance) the measured ARL0 is only a few hundred cycles: transform them
(e.g. log) before this detector.
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass, field
from typing import Any, Sequence

import numpy as np

from edge_monitor.stats.bias_em import check_gain
from edge_monitor.stats.densities import DENSITY_KINDS, DensityError, GaussianMixture, fit_density, min_points
from edge_monitor.stats.glr import GLRError, WindowedGLR, check_pf

log = logging.getLogger(__name__)

#: Per-test false-alarm probability of the agent's detectors (ARL0 ≥ 10⁴ cycles, docs/DETECTION.md).
DEFAULT_PF = 1e-9
#: Candidate change times kept by the agent's detectors [cycles].
DEFAULT_WINDOW = 100
#: Learning phase length [cycles] (ALGORITHMS.md §6: 50 … 70).
DEFAULT_NOMINAL = 60
#: GLR numerator mode. "recursive" is the O(W·K) variant (≈ 0.5 ms per update at W = 100, K ≤ 30);
#: "exact" is O(W²·K) (3 … 8 ms at K = 5 … 30, docs/benchmarks/glr.md). The ARL0/delay table in
#: docs/DETECTION.md was measured for the recursive mode, so it is the default.
DEFAULT_MODE = "recursive"


class DetectorConfigError(ValueError):
    """Invalid detector setting (names the parameter and the valid range)."""


@dataclass
class Decision:
    """The detector's answer for one cycle (fields of SYSTEM.md's ``decisions`` record)."""

    state: str                      # "learning" | "monitoring"
    statistic: float | None = None
    threshold: float | None = None
    alarm: bool = False
    change_cycle: int | None = None
    delta: list[float] | None = None
    miss_probability: float | None = None
    reason: str = ""
    cycle: int | None = None
    extra: dict[str, Any] = field(default_factory=dict)

    def to_record(self) -> dict[str, Any]:
        """The SYSTEM.md decision fields, JSON-ready (non-finite numbers become None)."""
        def clean(x: float | None) -> float | None:
            return None if x is None or not math.isfinite(x) else float(x)
        return {"state": self.state, "statistic": clean(self.statistic), "threshold": clean(self.threshold),
                "alarm": bool(self.alarm), "change_cycle": self.change_cycle,
                "delta": None if self.delta is None else [clean(v) for v in self.delta],
                "miss_probability": clean(self.miss_probability)}


class SequentialDetector:
    """Learning (``n_nominal`` finite values) → monitoring with a window-limited GLR.

    Values are the per-cycle quantity in its own units; ``cycle`` is the agent's cycle number and
    is only used to report ``change_cycle``. If the nominal values are constant (no density can be
    fitted), the detector keeps learning on a sliding window of the latest ``n_nominal`` values and
    says so in ``reason``; it starts monitoring as soon as the window shows any spread.
    """

    def __init__(self, dim: int = 1, n_nominal: int = DEFAULT_NOMINAL, density: str = "gce",
                 pf: float = DEFAULT_PF, window: int = DEFAULT_WINDOW, gamma0: float = 0.6,
                 rho: float = 1.0, mode: str = DEFAULT_MODE) -> None:
        if int(dim) < 1:
            raise DetectorConfigError(f"dim = {dim!r} must be ≥ 1")
        if density not in DENSITY_KINDS:
            raise DetectorConfigError(f"density = {density!r}; choose one of {DENSITY_KINDS}")
        need = min_points(density, int(dim))
        if int(n_nominal) < need:
            raise DetectorConfigError(f"n_nominal = {n_nominal!r} is too few for the {density!r} density "
                                      f"in dimension {dim}; use at least {need} (default {DEFAULT_NOMINAL})")
        if int(window) < 1:
            raise DetectorConfigError(f"window = {window!r} must be ≥ 1 cycle (default {DEFAULT_WINDOW})")
        if mode not in ("exact", "recursive"):
            raise DetectorConfigError(f"mode = {mode!r} must be 'exact' or 'recursive'")
        try:
            check_pf(pf)
            check_gain(gamma0, rho)
        except ValueError as exc:
            raise DetectorConfigError(str(exc)) from exc
        self.dim, self.n_nominal, self.density_kind = int(dim), int(n_nominal), density
        self.pf, self.window, self.gamma0, self.rho, self.mode = float(pf), int(window), float(gamma0), float(rho), mode
        self._nominal: list[list[float]] = []
        self._glr: WindowedGLR | None = None
        self._cycles: list[int | None] = [None] * self.window
        self._latched: dict[str, Any] | None = None
        self._learning_note = ""
        self.skipped_nonfinite = 0
        self.skipped_bad_shape = 0
        self.resets = 0

    @property
    def state(self) -> str:
        return "learning" if self._glr is None else "monitoring"

    @property
    def density(self) -> GaussianMixture | None:
        return None if self._glr is None else self._glr.density

    def update(self, value: float | Sequence[float], cycle: int) -> Decision:
        """Fold in one per-cycle value (scalar or ``dim``-vector) and return the decision."""
        vec, problem = self._as_vector(value)
        if vec is None:
            decision = self._current(cycle)
            decision.reason = problem
            return decision
        if self._glr is None:
            return self._learn(vec, cycle)
        return self._monitor(vec, cycle)

    def reset(self) -> None:
        """Declared maintenance: clear the alarm and the nominal model, learn again."""
        self._nominal.clear()
        self._glr = None
        self._cycles = [None] * self.window
        self._latched = None
        self._learning_note = ""
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

    def _learn(self, vec: np.ndarray, cycle: int) -> Decision:
        self._nominal.append(vec.tolist())
        if len(self._nominal) > self.n_nominal:
            del self._nominal[0]
        if len(self._nominal) < self.n_nominal:
            return Decision("learning", reason=self._learning_reason(), cycle=cycle)
        try:
            density = fit_density(np.asarray(self._nominal), self.density_kind)
            self._glr = WindowedGLR(density, self.window, self.pf, self.gamma0, self.rho, self.mode)
        except (DensityError, GLRError) as exc:
            self._learning_note = f"nominal data unusable, still learning: {exc}"
            log.info("detector stays in learning: %s", exc)
            return Decision("learning", reason=self._learning_note, cycle=cycle)
        self._nominal.clear()
        self._learning_note = ""
        log.info("nominal %s density learned (%d components); monitoring from cycle %s",
                 self.density_kind, density.n_components, cycle)
        return Decision("monitoring", threshold=self._glr.threshold, alarm=self._latched is not None,
                        reason=f"nominal density learned ({density.n_components} components)", cycle=cycle)

    def _learning_reason(self) -> str:
        return self._learning_note or f"learning {len(self._nominal)}/{self.n_nominal}"

    def _monitor(self, vec: np.ndarray, cycle: int) -> Decision:
        assert self._glr is not None
        result = self._glr.update(vec)
        self._cycles[result.index % self.window] = int(cycle)
        change_cycle = self._cycles[result.change_index % self.window]
        if result.alarm and self._latched is None:
            self._latched = {"cycle": int(cycle), "change_cycle": change_cycle, "statistic": result.statistic}
            log.warning("alarm at cycle %s: statistic %.3g ≥ %.3g, change since cycle %s",
                        cycle, result.statistic, result.threshold, change_cycle)
        reason = "alarm latched until reset()" if self._latched else "monitoring"
        return Decision("monitoring", result.statistic, result.threshold, self._latched is not None,
                        change_cycle, result.delta, result.miss_probability, reason, int(cycle),
                        {"segment_length": result.segment_length, "alarm_now": result.alarm})

    def _current(self, cycle: int) -> Decision:
        if self._glr is None:
            return Decision("learning", reason=self._learning_reason(), cycle=cycle)
        return Decision("monitoring", threshold=self._glr.threshold, alarm=self._latched is not None,
                        cycle=cycle)

    def state_dict(self) -> dict[str, Any]:
        return {"config": {"dim": self.dim, "n_nominal": self.n_nominal, "density": self.density_kind,
                           "pf": self.pf, "window": self.window, "gamma0": self.gamma0, "rho": self.rho,
                           "mode": self.mode},
                "nominal": [list(v) for v in self._nominal],
                "glr": None if self._glr is None else self._glr.state_dict(),
                "cycles": list(self._cycles), "latched": None if self._latched is None else dict(self._latched),
                "learning_note": self._learning_note, "counters": self.counters()}

    @classmethod
    def from_state(cls, state: dict[str, Any]) -> "SequentialDetector":
        det = cls(**state["config"])
        det._nominal = [list(map(float, v)) for v in state["nominal"]]
        det._glr = None if state["glr"] is None else WindowedGLR.from_state(state["glr"])
        det._cycles = [None if c is None else int(c) for c in state["cycles"]]
        det._latched = None if state["latched"] is None else dict(state["latched"])
        det._learning_note = state.get("learning_note", "")
        counters = state.get("counters", {})
        det.skipped_nonfinite = int(counters.get("skipped_nonfinite", 0))
        det.skipped_bad_shape = int(counters.get("skipped_bad_shape", 0))
        det.resets = int(counters.get("resets", 0))
        return det
