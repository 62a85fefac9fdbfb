"""How much one cycle's friction data tell about wear: data covariance, Fisher information and the
Cramér–Rao bound of ϖ (docs/ALGORITHMS.md §3), for the estimator and for experiment design.

Units: speeds rad/s, torques dimensionless, temperature °C, wear dimensionless; a bound is a variance
in wear units².
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.special import logsumexp

from joint_model import (
    DEFAULT_PARAMS,
    FRICTION_NOISE_STD,
    FrictionParams,
    friction_magnitude,
    jacobian_temperature_wear,
    load_sensitivity,
)

#: Monte Carlo draws and seed of the marginal Fisher information (N = 1), docs/ALGORITHMS.md §3.
_MARGINAL_FISHER_DRAWS = 200
_MARGINAL_FISHER_SEED = 20260402


def data_covariance(speeds: ArrayLike, load_std: float, noise_std: float,
                    params: FrictionParams = DEFAULT_PARAMS,
                    friction_stderr: ArrayLike | None = None) -> NDArray[np.float64]:
    """``Σ(v) = σ²·I + diag(stderr²) + σl²·s·sᵀ`` (N × N) of the friction data at ``speeds``."""
    v = np.atleast_1d(np.asarray(speeds, dtype=float))
    s = load_sensitivity(v, params)
    diag = np.full(v.size, noise_std ** 2)
    if friction_stderr is not None:
        diag = diag + np.atleast_1d(np.asarray(friction_stderr, dtype=float)) ** 2
    return np.diag(diag) + load_std ** 2 * np.outer(s, s)


def fisher_information(speeds: ArrayLike, temperature: float, wear: float, load_std: float,
                       noise_std: float = FRICTION_NOISE_STD, params: FrictionParams = DEFAULT_PARAMS,
                       friction_stderr: ArrayLike | None = None) -> NDArray[np.float64]:
    """``F = JᵀΣ⁻¹J`` (2 × 2, order [ξ, ϖ]) of the friction data for θ = [ξ, ϖ]."""
    v = np.atleast_1d(np.asarray(speeds, dtype=float))
    jac = jacobian_temperature_wear(v, temperature, wear, params)
    cov = data_covariance(v, load_std, noise_std, params, friction_stderr)
    return jac.T @ np.linalg.solve(cov, jac)


def crlb_wear(speeds: ArrayLike, temperature: float, wear: float, load_mean: float, load_std: float,
              params: FrictionParams = DEFAULT_PARAMS, noise_std: float = FRICTION_NOISE_STD,
              friction_stderr: ArrayLike | None = None) -> float:
    """Cramér–Rao bound ``[F⁻¹]₂₂`` of ϖ (a variance, wear units²) for data at ``speeds``.

    ``load_mean`` does not enter (the Jacobian is load-free; kept for a uniform signature).
    Returns ``inf`` when F is singular (N = 1, or coincident speeds: ξ and ϖ not separable).
    """
    del load_mean
    fisher = fisher_information(speeds, temperature, wear, load_std, noise_std, params, friction_stderr)
    return _crlb_std(fisher) ** 2


def marginal_fisher_wear(speeds: float | ArrayLike, wear: float, load_mean: float, load_std: float,
                         noise_std: float = FRICTION_NOISE_STD, params: FrictionParams = DEFAULT_PARAMS,
                         temperature_range: tuple[float, float] = (30.0, 50.0),
                         n_temperature_samples: int = 100, n_draws: int = _MARGINAL_FISHER_DRAWS,
                         seed: int = _MARGINAL_FISHER_SEED, friction_stderr: ArrayLike | None = None) -> float:
    """Fisher information of ϖ with ξ ~ U(range) marginalised (Monte Carlo), for N ≥ 1 data.

    The likelihood is ``p(τ|ϖ) = (1/Nξ)·Σi N(τ; μi(ϖ), Σ)`` with ``μi = τf(v; μl, ξi, ϖ)`` and Σ as
    in :func:`data_covariance`. Since ``∂μi/∂ϖ = g = ∂τw/∂ϖ`` for all i (wear is separable), the
    score is ``gᵀΣ⁻¹(τ − Σi wi·μi)`` (wi the posterior weights of the ξi), and ``F = E[score²]`` is
    estimated over ``n_draws`` draws ``ξ ~ U``, ``τ ~ N(τf(ξ), Σ)`` with a fixed seed (deterministic).
    For N = 1 this is the design criterion of §3; for N ≥ 2 it is the bound that applies when ξ
    is a random nuisance with that distribution (used by the Monte Carlo study).
    """
    v = np.atleast_1d(np.asarray(speeds, dtype=float)).reshape(-1)
    cov = data_covariance(v, load_std, noise_std, params, friction_stderr)
    chol = np.linalg.cholesky(cov)
    xi_grid = _temperature_samples(temperature_range, n_temperature_samples)
    means = friction_magnitude(v[None, :], load_mean, xi_grid[:, None], wear, params)      # (Nξ, N)
    rng = np.random.default_rng(seed)
    xi_draw = rng.uniform(temperature_range[0], temperature_range[1], n_draws)
    noise = rng.standard_normal((n_draws, v.size)) @ chol.T
    tau = friction_magnitude(v[None, :], load_mean, xi_draw[:, None], wear, params) + noise  # (Nf, N)
    white_tau = np.linalg.solve(chol, tau.T).T
    white_means = np.linalg.solve(chol, means.T).T
    d2 = np.sum((white_tau[:, None, :] - white_means[None, :, :]) ** 2, axis=2)             # (Nf, Nξ)
    log_w = -0.5 * d2
    weights = np.exp(log_w - logsumexp(log_w, axis=1, keepdims=True))
    gradient = jacobian_temperature_wear(v, float(np.mean(temperature_range)), wear, params)[:, 1]
    cov_inv_g = np.linalg.solve(cov, gradient)
    score = (tau - weights @ means) @ cov_inv_g
    return float(np.mean(score ** 2))


def _temperature_samples(temperature_range: tuple[float, float], n: int) -> NDArray[np.float64]:
    """Stratified midpoint samples of U(low, high): deterministic quadrature of the marginal."""
    low, high = temperature_range
    return low + (np.arange(n) + 0.5) / n * (high - low)


def _crlb_std(fisher: NDArray[np.float64]) -> float:
    """``√[F⁻¹]₂₂`` of a 2 × 2 Fisher matrix; inf if singular."""
    det = fisher[0, 0] * fisher[1, 1] - fisher[0, 1] ** 2
    if not np.isfinite(det) or det <= 1e-12 * fisher[0, 0] * fisher[1, 1] or det <= 0.0:
        return math.inf
    return math.sqrt(fisher[0, 0] / det)
