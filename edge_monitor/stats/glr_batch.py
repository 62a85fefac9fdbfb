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
"""

from __future__ import annotations

from typing import Literal, Sequence

import numpy as np
from numpy.typing import ArrayLike, NDArray

from edge_monitor.stats.bias_em import step_matrix
from edge_monitor.stats.densities import GaussianMixture

GLRMode = Literal["exact", "recursive"]


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
        self.gain = np.empty((b, d, d))
        for i, m in enumerate(mixtures):
            kk = m.n_components
            self.means[i, :kk] = m.means
            self.log_coef[i, :kk] = m._log_coef
            self.whiten[i] = m._whiten
            self.gain[i] = step_matrix(m, step)
        self.means_w = np.einsum("bkd,bed->bke", self.means, self.whiten)      # L⁻¹μk
        self.means_w_sq = np.einsum("bkd,bkd->bk", self.means_w, self.means_w)
        self._scalar = d == 1                                                   # the common case: plain broadcasting

    def _component_logpdf(self, x: NDArray[np.float64]) -> NDArray[np.float64]:
        """log(πk·N(x; μk, S)) for x of shape (B, n, d): (B, n, K)."""
        if self._scalar:
            z = x * self.whiten[:, :, 0][:, :, None] - self.means_w[:, None, :, 0]     # (B, n, K)
            return self.log_coef[:, None, :] - 0.5 * (z * z)
        xw = np.einsum("bnd,bed->bne", x, self.whiten)
        quad = (np.einsum("bnd,bnd->bn", xw, xw)[:, :, None] - 2.0 * np.einsum("bnd,bkd->bnk", xw, self.means_w)
                + self.means_w_sq[:, None, :])
        return self.log_coef[:, None, :] - 0.5 * np.maximum(quad, 0.0)

    def logpdf(self, x: NDArray[np.float64]) -> NDArray[np.float64]:
        """log p0(x) for x of shape (B, n, d): (B, n)."""
        lc = self._component_logpdf(x)
        top = lc.max(axis=2)
        return top + np.log(np.exp(lc - top[:, :, None]).sum(axis=2))

    def posterior_mean(self, x: NDArray[np.float64]) -> NDArray[np.float64]:
        """Σk ζk(x) μk for x of shape (B, n, d): (B, n, d)."""
        lc = self._component_logpdf(x)
        z = np.exp(lc - lc.max(axis=2, keepdims=True))
        if self._scalar:
            return ((z * self.means[:, None, :, 0]).sum(axis=2) / z.sum(axis=2))[:, :, None]
        z /= z.sum(axis=2, keepdims=True)
        return np.einsum("bnk,bkd->bnd", z, self.means)


class BatchWindowedGLR:
    """B window-limited GLR detectors advancing together (see the module docstring).

    ``update(y)`` takes one observation per detector, shape (B, d), and returns the statistic of
    each, shape (B,). :attr:`best` holds, after each update, the slot of the maximising candidate.
    """

    def __init__(self, mixtures: MixtureBatch, window: int, gamma0: float = 0.6, rho: float = 1.0,
                 mode: GLRMode = "recursive") -> None:
        if mode not in ("exact", "recursive"):
            raise ValueError(f"mode = {mode!r} must be 'exact' or 'recursive'")
        b, d, w = mixtures.size, mixtures.dim, int(window)
        self.mix, self.window, self.gamma0, self.rho, self.mode = mixtures, w, float(gamma0), float(rho), mode
        self.count = 0
        self.obs = np.zeros((b, w, d))
        self.base = np.zeros((b, w))
        self.times = np.full(w, -1, dtype=np.int64)
        self.delta = np.zeros((b, w, d))
        self.sums = np.zeros((b, w))
        self.best = np.zeros(b, dtype=np.int64)

    def update(self, y: ArrayLike) -> NDArray[np.float64]:
        obs = np.asarray(y, dtype=float).reshape(self.mix.size, self.mix.dim)
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
            step = np.einsum("bad,bed->bae", step, self.mix.gain)
        delta = delta + gain[None, :, None] * step
        self.delta[:, active] = delta
        stats = self._statistics(obs, slot, active, delta)
        best = np.argmax(stats, axis=1)
        self.best = active[best]
        return np.maximum(stats[np.arange(stats.shape[0]), best], 0.0)

    def _statistics(self, obs: NDArray[np.float64], slot: int, active: NDArray[np.int64],
                    delta: NDArray[np.float64]) -> NDArray[np.float64]:
        if self.mode == "recursive":
            self.sums[:, active] += self.mix.logpdf(obs[:, None, :] - delta) - self.base[:, slot][:, None]
            return self.sums[:, active]
        times = self.times[active]
        inside = times[None, :] >= times[:, None]                                      # (candidate, observation)
        b, a, d = delta.shape
        shifted = self.obs[:, active][:, None, :, :] - delta[:, :, None, :]             # (B, A, A, d)
        loglik = self.mix.logpdf(shifted.reshape(b, a * a, d)).reshape(b, a, a)
        return np.sum(np.where(inside[None], loglik - self.base[:, active][:, None, :], 0.0), axis=2)

    def segment_length(self) -> NDArray[np.int64]:
        """ñ of the maximising candidate of each detector after the last update."""
        return self.count - 1 - self.times[self.best] + 1
