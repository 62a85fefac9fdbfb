"""The window-limited sequential GLR for B independent detectors at once (docs/ALGORITHMS.md §6).

Each of the B detectors has its own nominal mixture (the same family and dimension d, padded to a
common number of components K) and its own stream of observations; all advance in lockstep, so the
ring buffer of candidate change times is shared and every operation is one numpy call over
(B, W, K). The agent's detector is the case B = 1 (:class:`~edge_monitor.stats.glr.WindowedGLR`);
the threshold calibration simulates B ≫ 1 bootstrap detectors with exactly the same recursion
(:mod:`edge_monitor.stats.calibration`).

Per observation y of a detector: a new candidate change time t = n opens with Δ̂(t:n) = 0; every
candidate's SA-EM estimate is updated, Δ̂ ← Δ̂ + γñ·A·(y − Σk ζk(y − Δ̂)μk − Δ̂) with γñ = γ0·ñ^(−ρ)
and A = (S·F(0))⁻¹ (Fisher-scoring step, see :mod:`edge_monitor.stats.bias_em`); the numerator
log p0(y − Δ̂) − log p0(y) is accumulated with the estimate of this step ("recursive", O(W·K)) or
recomputed over the window with the latest estimate ("exact", O(W²·K)). The statistic is the largest
sum over the candidates. Units: those of the observed quantity; statistics in nats.

**Null hypothesis with a drift allowance** (project choice, docs/DETECTION.md). H0 may be the box
of shifts ``lower ≤ Δ ≤ upper`` instead of Δ = 0: the denominator is then p0 at the shift of H0
closest to the estimate, ``log p0(y − Δ̂) − log p0(y − Δc)``, Δc the box point nearest Δ̂ in the
metric of the nominal's covariance: ``clip(Δ̂, lower, upper)`` in one dimension, a small quadratic
programme in several (:mod:`~edge_monitor.stats.null_projection`; clipping each axis alone overstates
a shift along one of two correlated axes). For one Gaussian component this is exactly the GLR of the
composite null; for mixtures the same projection with the mixture's covariance. A one-sided
test for an increase is ``lower = −∞, upper = 0``; an allowance ``a`` moves ``upper`` to ``a``, so
slow drifts smaller than ``a`` (the CUSUM reference value in classical SPC) do not accumulate.
With ``lower = upper = 0`` the recursion is the plain two-sided GLR above, bit for bit.

**Winsorised observations** (project choice). A nominal density learned from 60 values cannot show
its tails, and a Gaussian-kernel mixture has thinner tails than most real quantities: one value a
few standard deviations out then gives a likelihood ratio that no simulation from the fitted density
reproduces, and the calibrated threshold is too low. Observations may therefore be clipped to
``[clip_lo, clip_hi]`` (the nominal mean ± c standard deviations, :func:`clip_range`) before they
enter the recursion; the calibration clips its simulated streams the same way. A real shift moves
many values and is still detected by accumulation.
"""

from __future__ import annotations

from typing import Any, Literal, Sequence

import numpy as np
from numpy.typing import ArrayLike, NDArray

from edge_monitor.stats.bias_em import step_matrix
from edge_monitor.stats.densities import GaussianMixture
from edge_monitor.stats.null_projection import BoxProjector, covariance_precision

GLRMode = Literal["exact", "recursive"]
#: Directions of change a detector looks for: any shift, or only an increase (componentwise).
DIRECTIONS = ("both", "increase")


def null_box(nominal: ArrayLike, direction: str = "both", allowance: float = 0.0
             ) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """The shifts H0 allows for a detector that learned ``nominal`` (N0 × d): ``allowance`` standard
    deviations of the nominal values on either side, or below for ``direction="increase"``
    (then any decrease is nominal too). Returns ``(lower, upper)``, each (d,)."""
    values = np.asarray(nominal, dtype=float)
    if direction not in DIRECTIONS:
        raise ValueError(f"direction = {direction!r}; choose one of {DIRECTIONS}")
    spread = float(allowance) * values.std(axis=0, ddof=1) if allowance else np.zeros(values.shape[1])
    lower = np.full(values.shape[1], -np.inf) if direction == "increase" else -spread
    return lower, spread


def clip_range(nominal: ArrayLike, clip_sigma: float) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Where observations are winsorised for a detector that learned ``nominal`` (N0 × d): the
    nominal mean ± ``clip_sigma`` standard deviations per dimension (±inf when ``clip_sigma`` is 0)."""
    values = np.asarray(nominal, dtype=float)
    if not clip_sigma:
        return np.full(values.shape[1], -np.inf), np.full(values.shape[1], np.inf)
    centre, spread = values.mean(axis=0), float(clip_sigma) * values.std(axis=0, ddof=1)
    return centre - spread, centre + spread


def stack_bounds(pairs: list[tuple[NDArray[np.float64], NDArray[np.float64]]]
                 ) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Per-detector ``(lo, hi)`` pairs (each (d,)) as the (B, d) rows :class:`BatchWindowedGLR` takes."""
    return np.array([p[0] for p in pairs]), np.array([p[1] for p in pairs])


def _bounds(pair: tuple[ArrayLike, ArrayLike] | None, default: tuple[float, float], shape: tuple[int, int]
            ) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """``(lo, hi)`` broadcast to ``shape`` (``default`` when None); NaN refused."""
    lo, hi = (np.broadcast_to(np.asarray(v, dtype=float), shape).copy() for v in (pair or default))
    if np.any(np.isnan(lo)) or np.any(np.isnan(hi)):
        raise ValueError("bounds must not be NaN (use ±inf for an open side)")
    return lo, hi


class MixtureBatch:
    """B Gaussian mixtures of one dimension d, padded to K components (padding has weight 0)."""

    def __init__(self, mixtures: Sequence[GaussianMixture], step: str = "fisher") -> None:
        if not mixtures:
            raise ValueError("MixtureBatch needs at least one mixture")
        d = mixtures[0].dim
        if any(m.dim != d for m in mixtures):
            raise ValueError("MixtureBatch: all mixtures must have the same dimension")
        b, k = len(mixtures), max(m.n_components for m in mixtures)
        self.dim, self.size, self.n_components = d, b, k
        self.means = np.zeros((b, k, d))
        self.log_coef = np.full((b, k), -np.inf)
        self.whiten = np.empty((b, d, d))
        self.cov = np.empty((b, d, d))                                         # the components' S
        self.gain = np.empty((b, d, d))
        for i, m in enumerate(mixtures):
            kk = m.n_components
            self.means[i, :kk] = m.means
            self.log_coef[i, :kk] = m.log_coef
            self.whiten[i] = m.whiten
            self.cov[i] = m.cov
            self.gain[i] = step_matrix(m, step)
        self.means_w = np.einsum("bkd,bed->bke", self.means, self.whiten)      # L⁻¹μk
        self.means_w_sq = np.einsum("bkd,bkd->bk", self.means_w, self.means_w)
        self.whiten_t = np.ascontiguousarray(self.whiten.transpose(0, 2, 1))     # x @ whiten_t = (L⁻¹x)ᵀ
        self.means_w_t = np.ascontiguousarray(self.means_w.transpose(0, 2, 1))   # (B, d, K)
        self.gain_t = np.ascontiguousarray(self.gain.transpose(0, 2, 1))
        self._scalar = d == 1                                                   # the common case: plain broadcasting
        self._precision: NDArray[np.float64] | None = None

    @property
    def precision(self) -> NDArray[np.float64]:
        """(B, d, d) inverse of each mixture's covariance (the components' S plus the spread of their
        means): the metric in which the shift of H0 closest to an estimate is found."""
        if self._precision is None:
            weight = np.exp(self.log_coef - self.log_coef.max(axis=1, keepdims=True))
            weight /= weight.sum(axis=1, keepdims=True)
            centre = np.einsum("bk,bkd->bd", weight, self.means)
            spread = self.means - centre[:, None, :]
            cov = self.cov + np.einsum("bk,bkd,bke->bde", weight, spread, spread)
            self._precision = covariance_precision(cov)
        return self._precision

    def _component_logpdf(self, x: NDArray[np.float64], rows: Any = slice(None)) -> NDArray[np.float64]:
        """log(πk·N(x; μk, S)) for x of shape (B', n, d), the b-th with mixture ``rows[b]`` (default:
        all B in order): (B', n, K)."""
        if self._scalar:
            z = x * self.whiten[rows, :, 0][:, :, None] - self.means_w[rows][:, None, :, 0]    # (B', n, K)
            return self.log_coef[rows][:, None, :] - 0.5 * (z * z)
        xw = x @ self.whiten_t[rows]                                             # batched BLAS, not einsum
        quad = ((xw * xw).sum(axis=2)[:, :, None] - 2.0 * (xw @ self.means_w_t[rows])
                + self.means_w_sq[rows][:, None, :])
        return self.log_coef[rows][:, None, :] - 0.5 * np.maximum(quad, 0.0)

    def logpdf(self, x: NDArray[np.float64], rows: Any = slice(None)) -> NDArray[np.float64]:
        """log p0(x) for x of shape (B', n, d), mixtures as in :meth:`_component_logpdf`: (B', n)."""
        lc = self._component_logpdf(x, rows)
        top = lc.max(axis=2)
        return top + np.log(np.exp(lc - top[:, :, None]).sum(axis=2))

    def logpdf_rows(self, rows: NDArray[np.int64], x: NDArray[np.float64]) -> NDArray[np.float64]:
        """log p0 of mixture ``rows[m]`` at ``x[m]``, x of shape (M, d): (M,) — for scattered points."""
        return self.logpdf(x[:, None, :], rows)[:, 0]

    def posterior_mean(self, x: NDArray[np.float64]) -> NDArray[np.float64]:
        """Σk ζk(x) μk for x of shape (B, n, d): (B, n, d)."""
        lc = self._component_logpdf(x)
        z = np.exp(lc - lc.max(axis=2, keepdims=True))
        if self._scalar:
            return ((z * self.means[:, None, :, 0]).sum(axis=2) / z.sum(axis=2))[:, :, None]
        z /= z.sum(axis=2, keepdims=True)
        return z @ self.means


class BatchWindowedGLR:
    """B window-limited GLR detectors advancing together (see the module docstring).

    ``update(y)`` takes one observation per detector, shape (B, d), and returns the statistic of
    each, shape (B,). :attr:`best` holds, after each update, the slot of the maximising candidate.
    ``null_box``: optional ``(lower, upper)``, each broadcastable to (B, d), the shifts H0 allows
    (units of the observations; ``-inf``/``inf`` for an open side); default Δ = 0. ``clip``: optional
    ``(lo, hi)`` of the same shape, where observations are winsorised; default none.
    """

    def __init__(self, mixtures: MixtureBatch, window: int, gamma0: float = 0.6, rho: float = 1.0,
                 mode: GLRMode = "recursive", null_box: tuple[ArrayLike, ArrayLike] | None = None,
                 clip: tuple[ArrayLike, ArrayLike] | None = None) -> None:
        if mode not in ("exact", "recursive"):
            raise ValueError(f"mode = {mode!r} must be 'exact' or 'recursive'")
        b, d, w = mixtures.size, mixtures.dim, int(window)
        self.lower, self.upper = _bounds(null_box, (0.0, 0.0), (b, d))
        if np.any(self.lower > 0) or np.any(self.upper < 0):
            raise ValueError("null_box must contain Δ = 0: lower ≤ 0 ≤ upper")
        self.simple_null = not (np.any(self.lower) or np.any(self.upper))
        self.clip_lo, self.clip_hi = _bounds(clip, (-np.inf, np.inf), (b, d))
        if np.any(self.clip_lo >= self.clip_hi):
            raise ValueError("clip must be (lo, hi) with lo < hi")
        self.mix, self.window, self.gamma0, self.rho, self.mode = mixtures, w, float(gamma0), float(rho), mode
        self.count = 0
        self.obs = np.zeros((b, w, d))
        self.base = np.zeros((b, w))
        self.times = np.full(w, -1, dtype=np.int64)
        self.delta = np.zeros((b, w, d))
        self.sums = np.zeros((b, w))
        self.best = np.zeros(b, dtype=np.int64)
        self._projector: BoxProjector | None = None

    def update(self, y: ArrayLike) -> NDArray[np.float64]:
        obs = np.clip(np.asarray(y, dtype=float).reshape(self.mix.size, self.mix.dim), self.clip_lo, self.clip_hi)
        now, slot = self.count, self.count % self.window
        self.count += 1
        self.obs[:, slot] = obs
        self.base[:, slot] = self.mix.logpdf(obs[:, None, :])[:, 0]
        self.times[slot] = now
        self.delta[:, slot] = 0.0
        self.sums[:, slot] = 0.0
        active = np.flatnonzero(self.times >= 0)
        lengths = (now - self.times[active] + 1).astype(float)
        delta = self.delta[:, active]                                                   # (B, A, d)
        target = obs[:, None, :] - self.mix.posterior_mean(obs[:, None, :] - delta)
        gain = self.gamma0 * lengths ** (-self.rho)
        step = target - delta
        if self.mix.dim == 1:
            step = step * self.mix.gain[:, None, :, 0]
        else:
            step = step @ self.mix.gain_t
        delta = delta + gain[None, :, None] * step
        self.delta[:, active] = delta
        stats = self._statistics(obs, slot, active, delta)
        best = np.argmax(stats, axis=1)
        self.best = active[best]
        return np.maximum(stats[np.arange(stats.shape[0]), best], 0.0)

    def null_shift(self, delta: NDArray[np.float64]) -> NDArray[np.float64]:
        """The shift of H0 closest to each estimate in the nominal's metric (``clip(Δ̂, lower, upper)``
        in one dimension; :mod:`~edge_monitor.stats.null_projection`), delta (B, A, d)."""
        if self.mix.dim == 1:
            return np.clip(delta, self.lower[:, None, :], self.upper[:, None, :])
        if self._projector is None:          # fixed bounds and metric: its per-set solves once
            self._projector = BoxProjector(self.lower, self.upper, self.mix.precision)
        return self._projector(delta)

    def _statistics(self, obs: NDArray[np.float64], slot: int, active: NDArray[np.int64],
                    delta: NDArray[np.float64]) -> NDArray[np.float64]:
        if self.mode == "recursive":
            if self.simple_null:
                self.sums[:, active] += self.mix.logpdf(obs[:, None, :] - delta) - self.base[:, slot][:, None]
            else:
                self.sums[:, active] += self._log_ratio_beyond_null(obs, delta)
            return self.sums[:, active]
        times = self.times[active]
        inside = times[None, :] >= times[:, None]                                      # (candidate, observation)
        b, a, d = delta.shape
        window_obs = self.obs[:, active][:, None, :, :]                                 # (B, 1, A, d)
        loglik = self.mix.logpdf((window_obs - delta[:, :, None, :]).reshape(b, a * a, d)).reshape(b, a, a)
        if self.simple_null:
            null = self.base[:, active][:, None, :]
        else:
            shifted = window_obs - self.null_shift(delta)[:, :, None, :]
            null = self.mix.logpdf(shifted.reshape(b, a * a, d)).reshape(b, a, a)
        return np.sum(np.where(inside[None], loglik - null, 0.0), axis=2)

    def _log_ratio_beyond_null(self, obs: NDArray[np.float64], delta: NDArray[np.float64]) -> NDArray[np.float64]:
        """log p0(y − Δ̂) − log p0(y − clip(Δ̂)) per candidate, (B, A): exactly 0 where Δ̂ lies inside
        H0's box (both terms are the same point), so the density is evaluated only for the others."""
        allowed = self.null_shift(delta)
        rows, cols = np.nonzero(np.any(allowed != delta, axis=2))
        out = np.zeros(delta.shape[:2])
        if rows.size:
            y = obs[rows]
            points = np.concatenate([y - delta[rows, cols], y - allowed[rows, cols]])
            both = self.mix.logpdf_rows(np.concatenate([rows, rows]), points)
            out[rows, cols] = both[: rows.size] - both[rows.size:]
        return out

    def segment_length(self) -> NDArray[np.int64]:
        """ñ of the maximising candidate of each detector after the last update."""
        return self.count - 1 - self.times[self.best] + 1
