"""Per-quantity sequential detector of the agent: learning phase, then window-limited GLR.

One detector watches one per-cycle quantity (wear estimate, log ``kl.raw``, log ``kl.weighted``) or a
vector of them (``dim`` > 1). It collects ``n_nominal`` finite values, fits the nominal density
(docs/ALGORITHMS.md §5) and then runs :class:`~edge_monitor.stats.glr.WindowedGLR` on every new value.
An alarm is latched after the first threshold crossing until :meth:`SequentialDetector.reset` (a
declared maintenance), which also restarts learning. Non-finite values are skipped and counted and
never touch the state.

Default false-alarm probability per test: :data:`DEFAULT_PF` (scalar quantities) and
:data:`DEFAULT_PF_VECTOR` (the joint vector), the values at which the measured run length to false
alarm (ARL0) of the windowed test on the agent's quantities reached 10⁴ cycles (docs/DETECTION.md).
"""

from __future__ import annotations

import logging
from dataclasses import asdict, dataclass, replace
from typing import Any, Sequence

import numpy as np

from edge_monitor.errors import ConfigError, check_learned_with, require
from edge_monitor.records import Decision
from edge_monitor.stats.bias_em import BiasEMError, check_gain
from edge_monitor.stats.densities import DENSITY_KINDS, DensityError, GaussianMixture, fit_density, min_points
from edge_monitor.stats.glr import GLRError, WindowedGLR, check_pf

log = logging.getLogger(__name__)

#: Per-test false-alarm probability of the agent's scalar detectors (docs/DETECTION.md).
DEFAULT_PF = 1e-11
#: The same for a vector quantity (the 3-d joint vector needs a lower Pf for the same ARL0).
DEFAULT_PF_VECTOR = 1e-12
#: Candidate change times kept by the agent's detectors [cycles].
DEFAULT_WINDOW = 100
#: Largest window [cycles]: memory and time per cycle are O(window).
MAX_WINDOW = 10_000
#: Learning phase length [cycles] (docs/ALGORITHMS.md §6: 50 … 70).
DEFAULT_NOMINAL = 60
#: Longest learning phase [cycles]: the nominal values are kept until the density is fitted.
MAX_NOMINAL = 10_000
#: GLR numerator mode. "recursive" is the O(W·K) variant (≈ 0.5 ms per update at W = 100, K ≤ 30);
#: "exact" is O(W²·K) (3 … 8 ms at K = 5 … 30, docs/benchmarks/glr.md). The ARL0/delay table in
#: docs/DETECTION.md was measured for the recursive mode, so it is the default.
DEFAULT_MODE = "recursive"


class DetectorConfigError(ConfigError):
    """Invalid detector setting (names the parameter and the valid range)."""


@dataclass(frozen=True)
class DetectorConfig:
    """Settings of one sequential detector, validated once, here (``where`` prefixes messages)."""

    dim: int = 1
    n_nominal: int = DEFAULT_NOMINAL
    density: str = "gce"
    pf: float = DEFAULT_PF
    window: int = DEFAULT_WINDOW
    gamma0: float = 0.6
    rho: float = 1.0
    mode: str = DEFAULT_MODE

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
        except ConfigError as exc:
            raise DetectorConfigError(str(exc)) from None
        for name, check in (("pf", lambda: check_pf(self.pf)), ("gamma0", lambda: check_gain(self.gamma0, 0.75)),
                            ("rho", lambda: check_gain(0.5, self.rho))):
            try:
                check()
            except (GLRError, BiasEMError) as exc:
                raise DetectorConfigError(f"{name}: {exc}") from None

    def fingerprint(self) -> dict[str, Any]:
        return asdict(self)


class SequentialDetector:
    """Learning (``n_nominal`` finite values) → monitoring with a window-limited GLR.

    Values are the per-cycle quantity in its own units; ``cycle`` is the agent's cycle number and
    is only used to report ``change_cycle``. If the nominal values are constant (no density can be
    fitted), the detector keeps learning on a sliding window of the latest ``n_nominal`` values and
    says so in ``reason``; it starts monitoring as soon as the window shows any spread.
    """

    def __init__(self, config: DetectorConfig = DetectorConfig()) -> None:
        self.config = config
        self.dim, self.n_nominal, self.density_kind = config.dim, config.n_nominal, config.density
        self.pf, self.window, self.gamma0, self.rho, self.mode = (config.pf, config.window, config.gamma0,
                                                                  config.rho, config.mode)
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
    def alarmed(self) -> bool:
        """Whether an alarm is latched (until :meth:`reset`)."""
        return self._latched is not None

    @property
    def density(self) -> GaussianMixture | None:
        return None if self._glr is None else self._glr.density

    def update(self, value: float | Sequence[float], cycle: int) -> Decision:
        """Fold in one per-cycle value (scalar or ``dim``-vector) and return the decision."""
        vec, problem = self._as_vector(value)
        if vec is None:
            return replace(self._current(), reason=problem)
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
            return Decision("learning", reason=self._learning_reason())
        try:
            density = fit_density(np.asarray(self._nominal), self.density_kind)
            self._glr = WindowedGLR(density, self.window, self.pf, self.gamma0, self.rho,
                                    "exact" if self.mode == "exact" else "recursive")
        except (DensityError, GLRError) as exc:
            self._learning_note = f"nominal data unusable, still learning: {exc}"
            log.info("detector stays in learning: %s", exc)
            return Decision("learning", reason=self._learning_note)
        self._nominal.clear()
        self._learning_note = ""
        log.info("nominal %s density learned (%d components); monitoring from cycle %s",
                 self.density_kind, density.n_components, cycle)
        return Decision("monitoring", threshold=self._glr.threshold, alarm=self._latched is not None,
                        reason=f"nominal density learned ({density.n_components} components)")

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
                        change_cycle, tuple(result.delta), result.miss_probability, reason)

    def _current(self) -> Decision:
        """The decision of a cycle whose value did not enter the detector (state unchanged)."""
        if self._glr is None:
            return Decision("learning", reason=self._learning_reason())
        return Decision("monitoring", threshold=self._glr.threshold, alarm=self._latched is not None)

    def idle(self, reason: str) -> Decision:
        """The decision of a cycle kept out of the detector (e.g. a partial cycle), with ``reason``."""
        return Decision(self.state, alarm=self._latched is not None, reason=reason)

    def state_dict(self) -> dict[str, Any]:
        return {"config": self.config.fingerprint(),
                "nominal": [list(v) for v in self._nominal],
                "glr": None if self._glr is None else self._glr.state_dict(),
                "cycles": list(self._cycles), "latched": None if self._latched is None else dict(self._latched),
                "learning_note": self._learning_note, "counters": self.counters()}

    @classmethod
    def from_state(cls, config: DetectorConfig, state: dict[str, Any]) -> "SequentialDetector":
        """Restore a detector learned with ``config``; :class:`StateMismatch` if it was learned with another."""
        check_learned_with("detector", state, config.fingerprint())
        det = cls(config)
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
