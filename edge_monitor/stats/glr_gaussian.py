"""The window-limited GLR of B detectors with Gaussian nominals, in closed form (calibration's fast path).

:class:`~edge_monitor.stats.glr_batch.BatchWindowedGLR` runs any Gaussian mixture; with one component
N(μ, S) its recursion (recursive numerator, Fisher-scoring step) reduces to a few array operations,
which the threshold calibration runs for thousands of simulated detectors:

* SA-EM: the posterior mean is μ and the step matrix (S·F(0))⁻¹ is the identity, so every candidate's
  estimate is ``Δ̂ ← Δ̂ + γñ·(e − Δ̂)`` with ``e = y − μ`` (y winsorised) and ``γñ = γ0·ñ^(−ρ)``;
* numerator: ``log p0(y − Δ̂) − log p0(y − Δc) = ½·[q(e − Δc) − q(e − Δ̂)]`` with ``q(x) = xᵀS⁻¹x``,
  i.e. ``½·(Δc − Δ̂)ᵀS⁻¹(Δc + Δ̂ − 2e)``,
  and ``Δc`` the shift of H0 closest to Δ̂ in the metric S⁻¹ (its box; clip in one dimension, the
  projection of :mod:`~edge_monitor.stats.null_projection` in several, as the general code does);
* the statistic is the largest candidate sum, at least 0.

The same numbers as the general code to rounding (tests/test_glr_gaussian.py), about 10× faster.
Units: those of the observations; statistics in nats.
"""

from __future__ import annotations

import itertools

import numpy as np
from numpy.typing import ArrayLike, NDArray

from edge_monitor.stats.null_projection import BoxProjector, covariance_precision


class GaussianBatchGLR:
    """B detectors, each with its own nominal N(``means[b]``, ``covs[b]``) (d-dimensional), null box
    ``(lower, upper)`` and winsorising range ``(clip_lo, clip_hi)`` (each (B, d)); ``update(y)`` takes
    (B, d) and returns the B statistics."""

    def __init__(self, means: ArrayLike, covs: ArrayLike, window: int, gamma0: float, rho: float,
                 null_box: tuple[ArrayLike, ArrayLike], clip: tuple[ArrayLike, ArrayLike]) -> None:
        self.means = np.asarray(means, dtype=float)
        b, d = self.means.shape
        covs = np.asarray(covs, dtype=float).reshape(b, d, d)
        precision = np.linalg.inv(covs)
        self.precision = np.ascontiguousarray(precision.transpose(1, 2, 0))[:, :, :, None]   # (d, d, B, 1)
        lower, upper = (np.broadcast_to(np.asarray(v, dtype=float), (b, d)) for v in null_box)
        one_sided = d > 1 and bool(np.all(np.isneginf(lower)) and np.all(np.isfinite(upper)))
        self.lcp = _UpperBoxLCP(covs) if one_sided else None
        self.projector = BoxProjector(lower, upper, covariance_precision(covs)) if d > 1 and not one_sided else None
        # axis first: every operation below runs over contiguous (B, W) planes
        self.lower, self.upper = lower.T[:, :, None], upper.T[:, :, None]
        self.clip_lo, self.clip_hi = (np.broadcast_to(np.asarray(v, dtype=float), (b, d)) for v in clip)
        self.window, self.gamma0, self.rho = int(window), float(gamma0), float(rho)
        self.count = 0
        self.ages = np.full(self.window, -1, dtype=np.int64)     # candidate length − 1 per slot; −1: unused
        self.delta = np.zeros((d, b, self.window))
        self.sums = np.zeros((b, self.window))

    def restart(self, rows: ArrayLike) -> None:
        """Restart the statistic of the detectors ``rows`` (mask or indices), as an acknowledged alarm
        does: their candidates so far never count again; those opened from the next cycle on do."""
        self.sums[np.asarray(rows)] = -np.inf

    def update(self, y: ArrayLike) -> NDArray[np.float64]:
        obs = np.clip(np.asarray(y, dtype=float).reshape(self.means.shape), self.clip_lo, self.clip_hi)
        slot = self.count % self.window
        self.count += 1
        self.ages[self.ages >= 0] += 1
        self.ages[slot] = 0
        self.delta[:, :, slot] = 0.0
        self.sums[:, slot] = 0.0
        active = self.ages >= 0
        gain = np.where(active, self.gamma0 * (np.maximum(self.ages, 0) + 1.0) ** (-self.rho), 0.0)    # (W,)
        e = (obs - self.means).T[:, :, None]                                                           # (d, B, 1)
        self.delta += gain * (e - self.delta)
        if self.lcp is not None:          # one-sided box: the increment from the multipliers alone
            g = self.delta - self.upper
            mu = self.lcp.multipliers(g)
            self.sums += sum(mu[i] * (0.5 * g[i] - self.delta[i] + e[i]) for i in range(len(mu)))
            return np.maximum(self.sums.max(axis=1), 0.0)
        if self.projector is None:
            allowed = np.clip(self.delta, self.lower, self.upper)
        else:                      # the box point nearest Δ̂ in the metric S⁻¹ (null_projection)
            allowed = self.projector(self.delta.transpose(1, 2, 0)).transpose(2, 0, 1)
        # q(e − Δc) − q(e − Δ̂) = (Δc − Δ̂)ᵀ S⁻¹ (Δc + Δ̂ − 2e): d² operations over (B, W) planes
        moved = allowed - self.delta
        total = allowed + self.delta - 2.0 * e
        dim = e.shape[0]
        if dim == 1:
            self.sums += (0.5 * self.precision[0, 0]) * moved[0] * total[0]
            return np.maximum(self.sums.max(axis=1), 0.0)
        acc = np.zeros(self.sums.shape)
        for i in range(dim):
            row = moved[0] * self.precision[i, 0]
            for j in range(1, dim):
                row += moved[j] * self.precision[i, j]
            acc += row * total[i]
        self.sums += 0.5 * acc
        return np.maximum(self.sums.max(axis=1), 0.0)


class _UpperBoxLCP:
    """H0's nearest point for the box Δ ≤ u, through its multipliers: with r = Δ̂ − Δc = S·μ and
    g = Δ̂ − u, μ solves the linear complementarity problem μ ≥ 0, w = S·μ − g ≥ 0, μᵀw = 0 (the
    optimality conditions of min rᵀS⁻¹r over r ≥ g). Each active set A (μ_A > 0, w_A = 0) gives
    μ_A = (S_AA)⁻¹ g_A; the one whose μ_A ≥ 0 and w_F ≥ 0 is the solution. Over (B, W) planes with
    per-detector coefficients, no gathers. The GLR increment is then μᵀ(½g − Δ̂ + e)."""

    def __init__(self, covs: NDArray[np.float64]) -> None:
        d = covs.shape[1]
        self.dim = d
        self.cov = [[covs[:, i, j][:, None] for j in range(d)] for i in range(d)]
        self.sets: list[tuple[list[int], list[int], list[list[NDArray[np.float64]]]]] = []
        for k in range(1, d + 1):
            for active in itertools.combinations(range(d), k):
                a = list(active)
                inv: NDArray[np.float64] = np.linalg.inv(covs[:, a][:, :, a]).astype(np.float64)
                self.sets.append((a, [i for i in range(d) if i not in a],
                                  [[inv[:, m, n][:, None] for n in range(k)] for m in range(k)]))

    def multipliers(self, g: NDArray[np.float64]) -> list[NDArray[np.float64]]:
        """μ (d arrays (B, W)) for g = Δ̂ − u (d, B, W); 0 where Δ̂ is inside the box."""
        d = self.dim
        mu: list[NDArray[np.float64]] = [np.zeros(g.shape[1:]) for _ in range(d)]
        found = np.all(g <= 0.0, axis=0)
        for a, free, inv in self.sets:
            m_a = [sum(inv[m][n] * g[a[n]] for n in range(len(a))) for m in range(len(a))]
            ok = ~found
            for v in m_a:
                ok &= v >= 0.0
            for f in free:
                ok &= sum(self.cov[f][a[n]] * m_a[n] for n in range(len(a))) >= g[f]
            for n, i in enumerate(a):
                mu[i] = np.where(ok, m_a[n], mu[i])
            found |= ok
        return mu
