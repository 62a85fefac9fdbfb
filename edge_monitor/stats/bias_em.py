"""Estimating a bias change Δ of a nominal mixture, H1: p1(y) = p0(y − Δ) (docs/ALGORITHMS.md §6).

:func:`em_bias` is the batch EM; :class:`SAEMBias` the sequential stochastic-approximation EM
recursion ``Δ̂ ← γñ·Σk ζk(Δ̂)(y − μk) + (1 − γñ)·Δ̂`` with ``γñ = γ0·ñ^(−ρ)``. Δ is in the units of y.

Step choice (a deviation by default, see :class:`SAEMBias`): the literal recursion (``step="em"``)
has mean-field slope a = S·F(0) at the root (S the kernel covariance, F(0) the Fisher information
for location). For one Gaussian component a = 1, but for a KDE or GCE mixture a ≈ 0.1 … 0.4, and a
Robbins–Monro recursion with gain γ0/ñ and γ0·a < ½ converges only like ñ^(−γ0·a): measured on
skewed data, Δ̂ reached 0.77 of the batch EM value after 20 000 observations with a KDE. The default
``step="fisher"`` multiplies the EM step by (S·F(0))⁻¹ (Fisher scoring). It is identical to the
literal recursion for a Gaussian density and converges like 1/√ñ for every mixture.
"""

from __future__ import annotations

from typing import Any, Literal

import numpy as np
from numpy.typing import ArrayLike, NDArray

from edge_monitor.stats.densities import GaussianMixture, as_observations


class BiasEMError(ValueError):
    """Invalid settings of the bias estimators (names the parameter and its valid range)."""


def em_bias(y: ArrayLike, density: GaussianMixture, tol: float = 1e-10,
            max_iter: int = 500, accelerate: bool = True) -> NDArray[np.float64]:
    """Maximum-likelihood Δ of p0(y − Δ) for the observations ``y`` (n, d) by EM.

    Start ``Δ0 = ȳ − Σk πk μk``; E-step ζnk ∝ πk·N(yn − Δ; μk, S); M-step
    ``Δ = (1/N)·Σn Σk ζnk (yn − μk)``; stop when ‖Δ(i) − Δ(i−1)‖² ≤ ``tol`` or after ``max_iter``.

    EM's rate is 1 − S·F(0) per iteration, slow for KDE-like mixtures (≈ 0.9). With
    ``accelerate`` each iteration also tries the EM step scaled by (S·F(0))⁻¹ and keeps it only if
    the log-likelihood does not drop below the plain EM step's, so the fixed point and monotone
    ascent of EM are kept while the iteration count falls about tenfold.
    """
    obs = as_observations(y, density.dim, name="test data")
    if len(obs) == 0:
        raise BiasEMError("em_bias: no observations")
    y_mean = obs.mean(axis=0)
    delta = y_mean - density.mean
    if density.n_components == 1:
        return delta
    scale = step_matrix(density, "fisher") if accelerate else None
    post, _ = density.posterior_mean_and_logpdf(obs - delta)
    for _ in range(max_iter):
        new = y_mean - post.mean(axis=0)
        post, loglik = density.posterior_mean_and_logpdf(obs - new)
        if scale is not None:
            trial = delta + scale @ (new - delta)
            trial_post, trial_loglik = density.posterior_mean_and_logpdf(obs - trial)
            if trial_loglik.sum() >= loglik.sum():
                new, post = trial, trial_post
        step = float(np.sum((new - delta) ** 2))
        delta = new
        if step <= tol:
            break
    return delta


def check_gain(gamma0: float, rho: float) -> None:
    """Validate the SA gain γñ = γ0·ñ^(−ρ): γ0 ∈ (0, 1), ρ ∈ (½, 1]."""
    if not 0.0 < gamma0 < 1.0:
        raise BiasEMError(f"gamma0 = {gamma0!r} must lie in (0, 1); the default is 0.6")
    if not 0.5 < rho <= 1.0:
        raise BiasEMError(f"rho = {rho!r} must lie in (0.5, 1]; the default is 1")


SAStep = Literal["fisher", "em"]


def check_step(step: str) -> None:
    if step not in ("fisher", "em"):
        raise BiasEMError(f"step = {step!r} must be 'fisher' (preconditioned, default) or 'em' (literal)")


def step_matrix(density: GaussianMixture, step: str) -> NDArray[np.float64]:
    """Matrix multiplying the EM step: (S·F(0))⁻¹ for ``"fisher"``, the identity for ``"em"``."""
    check_step(step)
    if step == "em":
        return np.eye(density.dim)
    return np.asarray(np.linalg.inv(density.cov @ density.fisher_location()), dtype=np.float64)


class SAEMBias:
    """Sequential SA-EM estimate of Δ from one observation at a time, starting at Δ̂ = 0.

    ``Δ̂ ← Δ̂ + γñ·A·(Σk ζk(Δ̂)(y − μk) − Δ̂)`` with A = (S·F(0))⁻¹ (``step="fisher"``, default) or
    A = I (``step="em"``, the literal docs/ALGORITHMS.md §6 recursion).
    """

    def __init__(self, density: GaussianMixture, gamma0: float = 0.6, rho: float = 1.0,
                 step: SAStep = "fisher") -> None:
        check_gain(gamma0, rho)
        self.density = density
        self.gamma0 = float(gamma0)
        self.rho = float(rho)
        self.step = step
        self._gain_matrix = step_matrix(density, step)
        self.count = 0
        self.delta = np.zeros(density.dim)

    def update(self, y: ArrayLike) -> NDArray[np.float64]:
        """Fold in one observation (d,) and return the new Δ̂ (d,)."""
        obs = as_observations(y, self.density.dim, name="observation")[0]
        self.count += 1
        gain = self.gamma0 * self.count ** (-self.rho)
        target = obs - self.density.posterior_mean(obs - self.delta)[0]
        self.delta = self.delta + gain * (self._gain_matrix @ (target - self.delta))
        return self.delta.copy()

    def state_dict(self) -> dict[str, Any]:
        return {"density": self.density.state_dict(), "gamma0": self.gamma0, "rho": self.rho,
                "step": self.step, "count": self.count, "delta": self.delta.tolist()}

    @classmethod
    def from_state(cls, state: dict[str, Any]) -> "SAEMBias":
        est = cls(GaussianMixture.from_state(state["density"]), state["gamma0"], state["rho"],
                  state.get("step", "fisher"))
        est.count = int(state["count"])
        est.delta = np.asarray(state["delta"], dtype=float)
        return est
