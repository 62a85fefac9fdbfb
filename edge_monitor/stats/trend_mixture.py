"""The ``multi_rate`` wear-trend model: drifting-rate Kalman filters at several rate drifts, weighted by how
well each predicted the recent estimates (dynamic model averaging: Raftery, Kárný & Ettler, Technometrics
2010; docs/PROGNOSIS.md).

How fast a joint's wear rate changes is not known in advance and changes over its life: a steady wear
wants a filter with a long memory (a precise rate), an accelerating one a short memory (a rate that
follows). Each filter k has the rate drift ``rate_drifts[k]``; its weight is ∝ exp(Σ forgetting^age ·
log-density of each estimate under the filter's prediction), so the weights follow which drift fits
now. The forecast is the weighted mixture of the filters' crossing-time distributions; level and rate
are the weighted means. Memory: one filter per drift.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
from numpy.typing import NDArray

from edge_monitor.errors import check_learned_with
from edge_monitor.stats.wear_trend import KalmanTrend, TrendConfig


class TrendMixture:
    """See the module docstring; the interface of :class:`~edge_monitor.stats.wear_trend.WearTrend`."""

    def __init__(self, config: TrendConfig) -> None:
        self.config = config
        self.filters = [KalmanTrend(config).with_rate_drift(q) for q in config.rate_drifts]
        self.log_weights = np.zeros(len(self.filters))       # forgotten sums of log-densities
        self.updates = 0

    @property
    def weights(self) -> NDArray[np.float64]:
        w = np.exp(self.log_weights - self.log_weights.max())
        return w / w.sum()

    def update(self, cycle: int, estimate: float | None, std: float | None) -> None:
        before = self.filters[0].updates
        for f in self.filters:
            f.update(cycle, estimate, std)
        if self.filters[0].updates > before:
            self.updates = self.filters[0].updates
            if before > 0:          # the first estimate initialises every filter alike
                fits = np.array([f.loglik for f in self.filters])
                self.log_weights = self.config.forgetting * self.log_weights + fits

    @property
    def rate_z(self) -> float:
        """The rate over its std in the filter that predicted the recent estimates best (the mixture's own
        spread includes the fast filters' noise: no rate would ever stand out of it)."""
        best = self.filters[int(np.argmax(self.log_weights))]
        return best.rate_z

    def _mean(self, values: list[float]) -> float:
        return float(np.dot(self.weights, values))

    @property
    def level(self) -> float:
        return self._mean([f.level for f in self.filters])

    @property
    def level_std(self) -> float:
        return self._spread([f.level for f in self.filters], [f.level_std for f in self.filters])

    @property
    def rate(self) -> float:
        return self._mean([f.rate for f in self.filters])

    @property
    def rate_std(self) -> float:
        return self._spread([f.rate for f in self.filters], [f.rate_std for f in self.filters])

    def _spread(self, means: list[float], stds: list[float]) -> float:
        """Standard deviation of the weighted mixture of N(means, stds²)."""
        m = self._mean(means)
        return math.sqrt(max(self._mean([s * s + (x - m) ** 2 for x, s in zip(means, stds)]), 0.0))

    def crossing_cdf(self, level: float, h: NDArray[np.float64]) -> NDArray[np.float64]:
        w = self.weights
        return np.sum([wk * f.crossing_cdf(level, h) for wk, f in zip(w, self.filters) if wk > 1e-6], axis=0) \
            / max(float(w[w > 1e-6].sum()), 1e-300)

    def state_dict(self) -> dict[str, Any]:
        return {"config": self.config.fingerprint(), "filters": [f.state_dict() for f in self.filters],
                "log_weights": self.log_weights.tolist()}

    @classmethod
    def from_state(cls, config: TrendConfig, state: dict[str, Any]) -> "TrendMixture":
        check_learned_with("prognosis", state, config.fingerprint())
        out = cls(config)
        filters, weights = state["filters"], np.asarray(state["log_weights"], dtype=float)
        if len(filters) != len(out.filters) or weights.shape != (len(out.filters),) or not np.all(np.isfinite(weights)):
            raise ValueError("saved wear trend: not a state the mixture could have saved")
        out.filters = [KalmanTrend.from_state(config, s).with_rate_drift(q)
                       for s, q in zip(filters, config.rate_drifts)]
        out.log_weights, out.updates = weights, out.filters[0].updates
        return out
