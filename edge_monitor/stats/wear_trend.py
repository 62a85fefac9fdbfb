"""Recursive wear-trend models of one joint: fed each cycle by the wear estimate and its standard
deviation, they give the distribution of the cycles until the wear reaches a level (docs/PROGNOSIS.md,
where the choice between them is measured).

* ``drifting_rate``: a local linear trend whose rate itself drifts — a Kalman filter on [level, rate]
  with the rate a random walk (``rate_drift`` q per cycle) and a small level diffusion
  (``level_diffusion``); the forecast extrapolates the rate with its uncertainty now. Its memory,
  ≈ (estimate variance / q)^¼ cycles, fixes the time scale of the wear it follows.
* ``multi_rate`` (the agent's): drifting-rate filters at rate drifts over eight decades, weighted by
  how well each predicted the recent estimates (:mod:`edge_monitor.stats.trend_mixture`): no time scale
  assumed.
* ``wiener``: a Wiener process with drift (the classic degradation model) — the same filter with a
  constant rate and the level diffusion σ² as the Wiener process's; its first passage is inverse
  Gaussian (:func:`~edge_monitor.stats.crossing_time.wiener_crossing_cdf`).
* ``accelerating``: level, rate and acceleration, the acceleration a random walk
  (``acceleration_drift``): a quadratic trend, for power and exponential laws.
* ``line``: the naive baseline — a straight line fitted by least squares through the last ``window``
  estimates, extrapolated with the uncertainty of the fitted line.

Every model has the shape of the agent's streaming estimators: ``update(cycle, estimate, std)``,
``state_dict()`` (JSON types) and ``from_state(config, state)``; its memory does not grow with the
number of cycles (a 2 × 2 or 3 × 3 covariance; the baseline's ``window`` estimates). A cycle without an
estimate moves the state on without a measurement. Cycles are the controller's test-cycle numbers.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass
from typing import Any, Protocol

import numpy as np
from numpy.typing import NDArray

from edge_monitor.errors import check_learned_with, require
from edge_monitor.records import is_finite_number
from edge_monitor.stats.crossing_time import gaussian_crossing_cdf, wiener_crossing_cdf

TREND_MODELS = ("drifting_rate", "multi_rate", "wiener", "accelerating", "line")


@dataclass(frozen=True)
class TrendConfig:
    """A trend model's settings (in the ``[prognosis]`` table), validated once, here. Units: wear (0 … 100)
    and cycles; ``rate_drift`` [(wear/cycle)²/cycle], ``acceleration_drift`` [(wear/cycle²)²/cycle],
    ``level_diffusion`` [wear²/cycle], ``initial_rate_std`` [wear/cycle], ``min_std`` [wear]."""

    model: str = "multi_rate"
    rate_drift: float = 1e-5
    acceleration_drift: float = 1e-12
    level_diffusion: float = 1e-3
    initial_rate_std: float = 0.05
    min_std: float = 1.0                 # floor of an estimate's std (a wild "± 0.01" cannot pin the level)
    noise_scale: float = 1.3             # the estimates scatter this many times their own std (measured)
    outlier_sigma: float = 3.0           # innovations winsorised at ± this many predicted std (0: off)
    window: int = 100                    # the line's estimates
    #: multi_rate: the filters' rate drifts, and the weight of the past in their likelihoods per estimate
    rate_drifts: tuple[float, ...] = (1e-9, 1e-8, 1e-7, 1e-6, 1e-5, 1e-4, 1e-3, 1e-2, 1e-1)
    forgetting: float = 0.97

    def __post_init__(self) -> None:
        require(self.model in TREND_MODELS, "prognosis.model", f"must be one of {TREND_MODELS}, got {self.model!r}")
        for name in ("rate_drift", "acceleration_drift", "level_diffusion"):
            value = getattr(self, name)
            require(math.isfinite(value) and 0 <= value <= 1e3, f"prognosis.{name}", f"must be 0 … 1000, got {value}")
        require(self.model != "wiener" or self.level_diffusion > 0, "prognosis.level_diffusion",
                "must be > 0 for the wiener model (its diffusion σ²)")
        require(math.isfinite(self.initial_rate_std) and 0 < self.initial_rate_std <= 100,
                "prognosis.initial_rate_std", f"must be in (0, 100] wear per cycle, got {self.initial_rate_std}")
        require(math.isfinite(self.min_std) and 0 < self.min_std <= 100, "prognosis.min_std",
                f"must be in (0, 100] wear, got {self.min_std}")
        require(math.isfinite(self.noise_scale) and 0.1 <= self.noise_scale <= 10, "prognosis.noise_scale",
                f"must be 0.1 … 10, got {self.noise_scale}")
        require(math.isfinite(self.outlier_sigma) and (self.outlier_sigma == 0 or self.outlier_sigma >= 1),
                "prognosis.outlier_sigma", f"must be 0 (off) or ≥ 1, got {self.outlier_sigma}")
        require(isinstance(self.window, int) and 3 <= self.window <= 100_000, "prognosis.window",
                f"must be 3 … 100000 estimates, got {self.window!r}")
        require(isinstance(self.rate_drifts, tuple) and 1 <= len(self.rate_drifts) <= 12 and all(
            is_finite_number(q) and 0 <= q <= 1e3 for q in self.rate_drifts),
            "prognosis.rate_drifts", f"need 1 … 12 rate drifts in [0, 1000], got {self.rate_drifts!r}")
        require(math.isfinite(self.forgetting) and 0.5 <= self.forgetting <= 1, "prognosis.forgetting",
                f"must be 0.5 … 1, got {self.forgetting}")

    def fingerprint(self) -> dict[str, Any]:
        return {k: list(v) if isinstance(v, tuple) else v for k, v in asdict(self).items()}


class WearTrend(Protocol):
    """What every trend model offers (see the module docstring)."""

    config: TrendConfig
    updates: int

    def update(self, cycle: int, estimate: float | None, std: float | None) -> None: ...

    @property
    def level(self) -> float: ...

    @property
    def level_std(self) -> float: ...

    @property
    def rate(self) -> float: ...

    @property
    def rate_std(self) -> float: ...

    @property
    def rate_z(self) -> float:
        """How many of its own standard deviations the rate is above 0 (the trend test)."""
        ...

    def crossing_cdf(self, level: float, h: NDArray[np.float64]) -> NDArray[np.float64]: ...

    def state_dict(self) -> dict[str, Any]: ...


def _measurement(estimate: float | None, std: float | None, floor: float, scale: float = 1.0
                 ) -> tuple[float, float] | None:
    """(estimate, variance) of a usable estimate, else None."""
    if estimate is None or std is None or not (math.isfinite(estimate) and math.isfinite(std)) or std < 0:
        return None
    return float(estimate), (scale * max(float(std), floor)) ** 2


def _z(rate: float, std: float) -> float:
    """``rate / std``; ±inf for a rate known exactly, NaN without a rate."""
    if not math.isfinite(rate):
        return math.nan
    return rate / std if std > 0 else math.copysign(math.inf, rate) if rate else 0.0


class KalmanTrend:
    """The ``drifting_rate``, ``wiener`` and ``accelerating`` models: a Kalman filter on [level, rate]
    or [level, rate, acceleration] (see the module docstring)."""

    def __init__(self, config: TrendConfig) -> None:
        self.config = config
        self.order = 3 if config.model == "accelerating" else 2
        self.x = np.zeros(self.order)
        self.p = np.zeros((self.order, self.order))
        self.cycle: int | None = None          # cycle of the state
        self.updates = 0                        # estimates taken
        self.winsorised = 0                     # … of which clipped to outlier_sigma
        self.loglik = 0.0                       # log-density the last estimate had under the prediction
        self.rate_drift = self._rate_drift()

    def _rate_drift(self) -> float:
        return 0.0 if self.config.model == "wiener" else self.config.rate_drift

    def with_rate_drift(self, q: float) -> "KalmanTrend":
        """This filter with the rate drift ``q`` instead of the configured one (a member of a mixture)."""
        self.rate_drift = float(q)
        return self

    def _transition(self, h: NDArray[np.float64]) -> NDArray[np.float64]:
        """First rows of the transition over ``h`` cycles, one per horizon: [1, h] or [1, h, h²/2]."""
        rows = [np.ones_like(h), h] + ([h * h / 2.0] if self.order == 3 else [])
        return np.stack(rows, axis=-1)

    def _noise(self, d: float) -> NDArray[np.float64]:
        """Process noise accumulated over ``d`` cycles."""
        c = self.config
        q = self.rate_drift * np.array([[d ** 3 / 3, d ** 2 / 2], [d ** 2 / 2, d]])
        out = np.zeros((self.order, self.order))
        out[:2, :2] = q
        out[0, 0] += c.level_diffusion * d
        if self.order == 3:
            j = c.acceleration_drift
            out += j * np.array([[d ** 5 / 20, d ** 4 / 8, d ** 3 / 6], [d ** 4 / 8, d ** 3 / 3, d ** 2 / 2],
                                 [d ** 3 / 6, d ** 2 / 2, d]])
        return out

    def update(self, cycle: int, estimate: float | None, std: float | None) -> None:
        """Move the state to ``cycle`` and take its estimate and std [wear] (``None``/NaN: none)."""
        measured = _measurement(estimate, std, self.config.min_std, self.config.noise_scale)
        if self.cycle is None:
            if measured is None:
                return
            self.x[:] = 0.0
            self.x[0] = measured[0]
            self.p = np.diag([measured[1], self.config.initial_rate_std ** 2] + [1e-6] * (self.order - 2))
            self.cycle, self.updates = int(cycle), 1
            return
        d = float(cycle - self.cycle)
        if d > 0:
            f = np.eye(self.order)
            f[0, 1] = d
            if self.order == 3:
                f[0, 2], f[1, 2] = d * d / 2.0, d
            self.x = f @ self.x
            self.p = f @ self.p @ f.T + self._noise(d)
            self.cycle = int(cycle)
        if measured is None:
            return
        z, r = measured
        s = self.p[0, 0] + r
        innovation = z - self.x[0]
        self.loglik = -0.5 * (math.log(2 * math.pi * s) + innovation * innovation / s)   # before winsorising
        limit = self.config.outlier_sigma * math.sqrt(s)
        if self.config.outlier_sigma > 0 and abs(innovation) > limit:
            innovation = math.copysign(limit, innovation)
            self.winsorised += 1
        gain = self.p[:, 0] / s
        self.x = self.x + gain * innovation
        self.p = self.p - np.outer(gain, self.p[0, :])
        self.p = (self.p + self.p.T) / 2.0
        self.updates += 1

    @property
    def level(self) -> float:
        return float(self.x[0]) if self.cycle is not None else math.nan

    @property
    def level_std(self) -> float:
        return math.sqrt(max(self.p[0, 0], 0.0)) if self.cycle is not None else math.nan

    @property
    def rate(self) -> float:
        return float(self.x[1]) if self.cycle is not None else math.nan

    @property
    def rate_std(self) -> float:
        return math.sqrt(max(self.p[1, 1], 0.0)) if self.cycle is not None else math.nan

    @property
    def rate_z(self) -> float:
        return _z(self.rate, self.rate_std)

    def crossing_cdf(self, level: float, h: NDArray[np.float64]) -> NDArray[np.float64]:
        """``P(the wear reaches level within h cycles)`` for each horizon of the increasing grid ``h``."""
        if self.cycle is None:
            return np.zeros_like(h)
        if self.config.model == "wiener":
            return wiener_crossing_cdf(h, level, self.level, self.p[0, 0], self.rate, self.p[1, 1],
                                       self.config.level_diffusion)
        rows = self._transition(h)
        mean = rows @ self.x
        var = np.einsum("hi,ij,hj->h", rows, self.p, rows)
        var += self.config.level_diffusion * h        # the rate's own future drift is not propagated
        now = float(gaussian_crossing_cdf(np.array([self.level]), np.array([self.p[0, 0]]), level)[0])
        return gaussian_crossing_cdf(mean, var, level, now)

    def state_dict(self) -> dict[str, Any]:
        return {"config": self.config.fingerprint(), "x": self.x.tolist(), "p": self.p.tolist(), "cycle": self.cycle,
                "updates": self.updates, "winsorised": self.winsorised}

    @classmethod
    def from_state(cls, config: TrendConfig, state: dict[str, Any]) -> "KalmanTrend":
        """Restore; :class:`~edge_monitor.errors.StateMismatch` for another config, ``ValueError`` for a
        state no filter could have saved."""
        check_learned_with("prognosis", state, config.fingerprint())
        out = cls(config)
        x, p = np.asarray(state["x"], dtype=float), np.asarray(state["p"], dtype=float)
        cycle = state["cycle"]
        if x.shape != (out.order,) or p.shape != (out.order, out.order) or not (
                np.all(np.isfinite(x)) and np.all(np.isfinite(p)) and np.all(np.diag(p) >= 0)):
            raise ValueError("saved wear trend: not a state a filter could have saved")
        if cycle is not None and not (isinstance(cycle, int) and not isinstance(cycle, bool)):
            raise ValueError(f"saved wear trend: cycle {cycle!r}")
        out.x, out.p, out.cycle = x, p, cycle
        out.updates, out.winsorised = int(state.get("updates", 0)), int(state.get("winsorised", 0))
        return out


class LineTrend:
    """The naive baseline: least squares through the last ``window`` estimates (unweighted), the
    crossing of the fitted line with the uncertainty of the line itself (see the module docstring)."""

    def __init__(self, config: TrendConfig) -> None:
        self.config = config
        self.cycles: list[int] = []
        self.values: list[float] = []
        self.updates = 0
        self.cycle: int | None = None

    def update(self, cycle: int, estimate: float | None, std: float | None) -> None:
        self.cycle = int(cycle) if self.cycle is None else max(self.cycle, int(cycle))
        if _measurement(estimate, std, self.config.min_std) is None:
            return
        self.cycles.append(int(cycle))
        self.values.append(float(estimate))       # type: ignore[arg-type]
        del self.cycles[:-self.config.window], self.values[:-self.config.window]
        self.updates += 1

    def _fit(self) -> tuple[float, float, float, float, float] | None:
        """(level now, slope, residual variance, mean cycle − now, Σ(c − mean)²) or None (< 3 estimates)."""
        if len(self.values) < 3 or self.cycle is None:
            return None
        c = np.asarray(self.cycles, dtype=float) - self.cycle
        y = np.asarray(self.values)
        cm = c.mean()
        sxx = float(((c - cm) ** 2).sum())
        if sxx <= 0:
            return None
        slope = float(((c - cm) * (y - y.mean())).sum() / sxx)
        level = float(y.mean() - slope * cm)
        resid = y - (level + slope * c)
        return level, slope, float((resid ** 2).sum() / (len(y) - 2)), float(cm), sxx

    @property
    def level(self) -> float:
        fit = self._fit()
        return math.nan if fit is None else fit[0]

    @property
    def level_std(self) -> float:
        fit = self._fit()
        return math.nan if fit is None else math.sqrt(fit[2] * (1 / len(self.values) + fit[3] ** 2 / fit[4]))

    @property
    def rate(self) -> float:
        fit = self._fit()
        return math.nan if fit is None else fit[1]

    @property
    def rate_std(self) -> float:
        fit = self._fit()
        return math.nan if fit is None else math.sqrt(fit[2] / fit[4])

    @property
    def rate_z(self) -> float:
        return _z(self.rate, self.rate_std)

    def crossing_cdf(self, level: float, h: NDArray[np.float64]) -> NDArray[np.float64]:
        fit = self._fit()
        if fit is None:
            return np.zeros_like(h)
        now_level, slope, var, cm, sxx = fit
        n = len(self.values)
        mean = now_level + slope * h
        line_var = var * (1 / n + (h - cm) ** 2 / sxx)
        now = float(gaussian_crossing_cdf(np.array([now_level]), np.array([var * (1 / n + cm ** 2 / sxx)]), level)[0])
        return gaussian_crossing_cdf(mean, line_var, level, now)

    def state_dict(self) -> dict[str, Any]:
        return {"config": self.config.fingerprint(), "cycles": list(self.cycles), "values": list(self.values),
                "updates": self.updates, "cycle": self.cycle}

    @classmethod
    def from_state(cls, config: TrendConfig, state: dict[str, Any]) -> "LineTrend":
        check_learned_with("prognosis", state, config.fingerprint())
        out = cls(config)
        cycles, values = [int(c) for c in state["cycles"]], [float(v) for v in state["values"]]
        if len(cycles) != len(values) or len(cycles) > config.window or not all(map(math.isfinite, values)):
            raise ValueError("saved wear trend: not a state the line could have saved")
        out.cycles, out.values, out.updates = cycles, values, int(state.get("updates", 0))
        out.cycle = state.get("cycle") if isinstance(state.get("cycle"), int) else (cycles[-1] if cycles else None)
        return out


def new_trend(config: TrendConfig) -> WearTrend:
    """A fresh model of the configured kind."""
    if config.model == "multi_rate":
        from edge_monitor.stats.trend_mixture import TrendMixture
        return TrendMixture(config)
    return LineTrend(config) if config.model == "line" else KalmanTrend(config)


def trend_from_state(config: TrendConfig, state: dict[str, Any]) -> WearTrend:
    """The configured model restored from ``state`` (errors as :meth:`KalmanTrend.from_state`)."""
    if config.model == "multi_rate":
        from edge_monitor.stats.trend_mixture import TrendMixture
        return TrendMixture.from_state(config, state)
    if config.model == "line":
        return LineTrend.from_state(config, state)
    return KalmanTrend.from_state(config, state)
