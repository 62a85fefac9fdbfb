"""Maximum-likelihood wear estimation from one cycle's friction data (ALGORITHMS.md §3).

Data: friction data ``τ ∈ R^N`` (dimensionless) at speeds ``|v|`` [rad/s] collected within one
cycle, which share temperature ξ [°C], load and wear ϖ. The controller's load estimate
``τl ~ N(μl, σl²)`` is marginalised (the model is linear in |τl|):

    τ ~ N(τf(v; μl, ξ, ϖ), Σ),   Σ = σ²·I + diag(stderr²) + σl²·s·sᵀ,   s(v) = ∂τf/∂|τl|.

* N ≥ 2: ``min rᵀΣ⁻¹r`` over ξmin ≤ ξ ≤ ξmax, 0 ≤ ϖ ≤ ϖmax, from the best point of a vectorised
  coarse grid, refined by ``scipy.optimize.least_squares`` (trust-region reflective, bounds) on the
  whitened residual ``L⁻¹r`` (Σ = L·Lᵀ). Σ does not depend on θ, so this is the exact ML estimate.
* N = 1: ξ ~ U(ξmin, ξmax) is marginalised with Nξ stratified (midpoint) samples, deterministic;
  the mixture likelihood is maximised over ϖ on a grid, refined by a bounded 1-D search.
* Uncertainty: the Cramér–Rao bound ``[F⁻¹]₂₂``, ``F = JᵀΣ⁻¹J`` at the estimate (N ≥ 2); for N = 1
  the Fisher information of the marginalised likelihood (:func:`marginal_fisher_wear`).
* Option ``method="marginal"``: N ≥ 2 treated like N = 1 (ξ marginalised). On data with ξ drawn per
  cycle from U(ξmin, ξmax) it is close to unbiased where the joint ML is biased low by ≈ 0.3–0.6
  standard deviations at the design speeds (tools/mc_wear_study.py, docs/WEAR_ESTIMATION.md).

Remark on the boundary ϖ = 0: ``∂τf/∂ϖ`` at ϖ = 0 is only ``fvϖ·v`` (the wear Stribeck term
vanishes faster than any power of ϖ), so the bound there is very large and, since the estimate
is truncated at 0, not a variance the estimate attains. It is published as computed.
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass
from typing import Sequence

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.optimize import least_squares, minimize_scalar
from scipy.special import logsumexp

from joint_model.friction import (
    DEFAULT_PARAMS,
    FRICTION_NOISE_STD,
    FrictionParams,
    friction_magnitude,
    jacobian_temperature_wear,
    load_sensitivity,
    wear_friction,
)

log = logging.getLogger(__name__)

#: Temperature grid step of the coarse start grid [°C] and wear grid step [-].
_GRID_TEMPERATURE_STEP = 1.0
_GRID_WEAR_STEP = 1.0
#: Local solver starts at most (local minima of the grid's wear profile).
_MAX_STARTS = 3
_COMPETITIVE_COST = 13.8
_SOLVER_METHOD = "trf"
#: Plausibility limits of the inputs: speeds [rad/s] (useful range ≤ 300), torques (fractions of
#: the joint's maximum torque, |τl| ≤ 0.75). Data beyond them are refused with a reason.
_MAX_PLAUSIBLE_SPEED = 1e4
_MAX_PLAUSIBLE_TORQUE = 10.0
#: Monte Carlo draws and seed of the marginal Fisher information (N = 1), ALGORITHMS.md §3.
_MARGINAL_FISHER_DRAWS = 200
_MARGINAL_FISHER_SEED = 20260402


@dataclass(frozen=True)
class WearEstimate:
    """One cycle's wear estimate. ``estimate``/``std`` in wear units, ``temperature`` in °C.

    ``reason`` is ``None`` for a valid estimate, otherwise why there is none (then ``estimate``
    and ``std`` are NaN). ``std`` is the Cramér–Rao standard deviation at the estimate.
    """

    estimate: float
    std: float
    temperature: float | None
    n_points: int
    reason: str | None = None

    @property
    def ok(self) -> bool:
        return self.reason is None

    def to_record(self) -> dict[str, float | None]:
        """The ``"wear"`` field of a symptom record (SYSTEM.md); NaN/inf become ``None``."""
        return {"estimate": _json_number(self.estimate), "std": _json_number(self.std),
                "temperature": None if self.temperature is None else _json_number(self.temperature)}


def _json_number(x: float) -> float | None:
    return float(x) if math.isfinite(x) else None


def _invalid(n_points: int, reason: str) -> WearEstimate:
    return WearEstimate(estimate=math.nan, std=math.nan, temperature=None, n_points=n_points, reason=reason)


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


#: ``"joint"``: ALGORITHMS.md §3 for N ≥ 2 (ML of [ξ, ϖ]); ``"marginal"``: ξ ~ U(range) marginalised for
#: every N (as §3 does for N = 1). See docs/WEAR_ESTIMATION.md for why the second is less biased.
ESTIMATION_METHODS = ("joint", "marginal")


class WearEstimator:
    """Per-cycle ML estimator of wear ϖ (and temperature ξ for N ≥ 2) from friction data.

    ``method="joint"`` (default, §3): N ≥ 2 by constrained weighted NLS in [ξ, ϖ], std = local CRLB
    √[F⁻¹]₂₂ at the estimate. ``method="marginal"``: N ≥ 2 like N = 1, ξ ~ U(range) marginalised,
    ξ̂ = posterior mean at ϖ̂, std from the marginal-likelihood Fisher information. N = 1 is always
    marginal. Stateless between cycles; :meth:`estimate` is deterministic and never raises on bad data.
    """

    def __init__(self, params: FrictionParams = DEFAULT_PARAMS, noise_std: float = FRICTION_NOISE_STD,
                 temperature_range: tuple[float, float] = (30.0, 50.0), wear_max: float = 100.0,
                 n_temperature_samples: int = 100, method: str = "joint") -> None:
        low, high = (float(x) for x in temperature_range)
        if not (math.isfinite(low) and math.isfinite(high) and low < high):
            raise ValueError(f"temperature_range: need finite low < high, got {temperature_range!r}")
        if not (math.isfinite(noise_std) and noise_std > 0):
            raise ValueError(f"noise_std: must be a positive number, got {noise_std!r}")
        if not (math.isfinite(wear_max) and wear_max > 0):
            raise ValueError(f"wear_max: must be a positive number, got {wear_max!r}")
        if method not in ESTIMATION_METHODS:
            raise ValueError(f"method: one of {ESTIMATION_METHODS}, got {method!r}")
        if int(n_temperature_samples) < 2:
            raise ValueError(f"n_temperature_samples: need ≥ 2, got {n_temperature_samples!r}")
        self.params = params
        self.noise_std = float(noise_std)
        self.temperature_range = (low, high)
        self.wear_max = float(wear_max)
        self.n_temperature_samples = int(n_temperature_samples)
        self.method = method
        n_xi = max(2, int(round((high - low) / _GRID_TEMPERATURE_STEP)) + 1)
        n_w = max(2, int(round(self.wear_max / _GRID_WEAR_STEP)) + 1)
        self._grid_xi = np.linspace(low, high, n_xi)
        self._grid_wear = np.linspace(0.0, self.wear_max, n_w)
        self._xi_samples = _temperature_samples(self.temperature_range, self.n_temperature_samples)

    # ------------------------------------------------------------------ public
    def estimate(self, speeds: Sequence[float] | ArrayLike, friction: Sequence[float] | ArrayLike,
                 load_mean: float, load_std: float,
                 friction_stderr: Sequence[float] | ArrayLike | None = None) -> WearEstimate:
        """Estimate ϖ from friction data ``friction`` at ``|speeds|`` [rad/s] of one cycle.

        ``load_mean``/``load_std``: the controller's load estimate and its std (dimensionless).
        ``friction_stderr``: optional per-datum standard errors, added to σ² on the diagonal.
        """
        try:
            checked = self._check(speeds, friction, load_mean, load_std, friction_stderr)
        except _BadData as exc:
            return _invalid(exc.n_points, str(exc))
        v, tau, mu_l, sigma_l, stderr = checked
        try:
            if v.size == 1 or self.method == "marginal":
                return self._estimate_marginal(v, tau, mu_l, sigma_l, stderr)
            return self._estimate_joint(v, tau, mu_l, sigma_l, stderr)
        except (np.linalg.LinAlgError, ValueError, FloatingPointError, OverflowError) as exc:  # never raise
            log.warning("wear estimation failed: %s", exc)
            return _invalid(int(v.size), f"numerical failure: {exc}")

    # ------------------------------------------------------------ validation
    def _check(self, speeds, friction, load_mean, load_std, friction_stderr):
        try:
            v = np.abs(np.atleast_1d(np.asarray(speeds, dtype=float)).reshape(-1))
            tau = np.atleast_1d(np.asarray(friction, dtype=float)).reshape(-1)
            stderr = None if friction_stderr is None else \
                np.atleast_1d(np.asarray(friction_stderr, dtype=float)).reshape(-1)
            mu_l, sigma_l = float(load_mean), float(load_std)
        except (TypeError, ValueError):
            raise _BadData(0, "non-numeric input") from None
        n = int(tau.size)
        if n == 0 or v.size == 0:
            raise _BadData(0, "no friction data")
        if v.size != n or (stderr is not None and stderr.size != n):
            raise _BadData(n, "length mismatch between speeds, friction and stderr")
        if not (np.all(np.isfinite(v)) and np.all(np.isfinite(tau))):
            raise _BadData(n, "non-finite datum")
        if stderr is not None and not (np.all(np.isfinite(stderr)) and np.all(stderr >= 0)):
            raise _BadData(n, "non-finite or negative friction stderr")
        if not (math.isfinite(mu_l) and math.isfinite(sigma_l) and sigma_l >= 0):
            raise _BadData(n, "non-finite load estimate or negative load std")
        if np.any(v <= 0):
            raise _BadData(n, "zero speed")
        if np.any(v > _MAX_PLAUSIBLE_SPEED) or np.any(np.abs(tau) > _MAX_PLAUSIBLE_TORQUE):
            raise _BadData(n, "implausible datum (speed or friction out of range)")
        if abs(mu_l) > _MAX_PLAUSIBLE_TORQUE or sigma_l > _MAX_PLAUSIBLE_TORQUE:
            raise _BadData(n, "implausible load estimate")
        return v, tau, abs(mu_l), sigma_l, stderr

    # ------------------------------------------------------------------ N ≥ 2
    def _estimate_joint(self, v, tau, mu_l, sigma_l, stderr) -> WearEstimate:
        cov = data_covariance(v, sigma_l, self.noise_std, self.params, stderr)
        chol = np.linalg.cholesky(cov)
        whiten = np.linalg.inv(chol)  # N is small (≤ a few tens): explicit L⁻¹ is cheap and exact enough
        p = self.params

        def residual(theta: NDArray[np.float64]) -> NDArray[np.float64]:
            return whiten @ (tau - friction_magnitude(v, mu_l, theta[0], theta[1], p))

        def jacobian(theta: NDArray[np.float64]) -> NDArray[np.float64]:
            return -whiten @ jacobian_temperature_wear(v, theta[0], theta[1], p)

        low = np.array([self.temperature_range[0], 0.0])
        high = np.array([self.temperature_range[1], self.wear_max])
        best_theta, best_cost = None, math.inf
        for start in self._grid_starts(v, tau, mu_l, whiten):
            x0 = np.clip(start, low, high)
            fit = least_squares(residual, x0, jac=jacobian, bounds=(low, high), method=_SOLVER_METHOD,
                                xtol=1e-8, ftol=1e-10, gtol=1e-10, max_nfev=50)
            for theta, cost in ((fit.x, fit.cost), (x0, 0.5 * float(np.sum(residual(x0) ** 2)))):
                if cost < best_cost:  # never worse than a grid start
                    best_theta, best_cost = theta, cost
        if best_theta is None or not np.isfinite(best_cost):
            return _invalid(int(v.size), "no finite fit")
        xi_hat, w_hat = float(best_theta[0]), float(best_theta[1])
        white_jac = whiten @ jacobian_temperature_wear(v, xi_hat, w_hat, p)
        std = _crlb_std(white_jac.T @ white_jac)
        return WearEstimate(estimate=w_hat, std=std, temperature=xi_hat, n_points=int(v.size))

    def _grid_starts(self, v, tau, mu_l, whiten) -> list[NDArray[np.float64]]:
        """Starts (ξ, ϖ) from the coarse grid (vectorised): the best ξ at each local minimum of the
        wear profile ``min_ξ cost(ξ, ϖ)``, best first, at most ``_MAX_STARTS``. Several starts are
        needed because the model is flat in ϖ near 0 (a local solver started there stays there)."""
        p = self.params
        nominal = friction_magnitude(v[None, :], mu_l, self._grid_xi[:, None], 0.0, p)  # (Nξ, N)
        wear = wear_friction(v[None, :], self._grid_wear[:, None], p)                     # (Nϖ, N)
        resid = tau[None, None, :] - nominal[:, None, :] - wear[None, :, :]                # (Nξ, Nϖ, N)
        white = resid @ whiten.T
        cost = np.einsum("ijk,ijk->ij", white, white)
        best_xi = np.argmin(cost, axis=0)
        profile = cost[best_xi, np.arange(cost.shape[1])]
        padded = np.concatenate([[np.inf], profile, [np.inf]])
        minima = np.flatnonzero((profile <= padded[:-2]) & (profile <= padded[2:]))
        minima = minima[np.argsort(profile[minima])][:_MAX_STARTS]
        # Other minima only if competitive: within a χ²(2) 99.9 % margin (13.8) of the best grid cost.
        minima = minima[profile[minima] <= profile[minima[0]] + _COMPETITIVE_COST]
        return [np.array([self._grid_xi[best_xi[j]], self._grid_wear[j]]) for j in minima]

    # ------------------------------------------------------------------- N = 1
    def _estimate_marginal(self, v, tau, mu_l, sigma_l, stderr) -> WearEstimate:
        """ML over ϖ of the ξ-marginalised likelihood (N = 1, or N ≥ 2 with ``method="marginal"``)."""
        p = self.params
        cov = data_covariance(v, sigma_l, self.noise_std, p, stderr)
        whiten = np.linalg.inv(np.linalg.cholesky(cov))
        white_tau = whiten @ tau
        white_nominal = friction_magnitude(v[None, :], mu_l, self._xi_samples[:, None], 0.0, p) @ whiten.T

        def log_weights(wear_values: ArrayLike) -> NDArray[np.float64]:
            """log N(τ; μ(ξi, ϖ), Σ) up to a constant, shape (len(wear_values), Nξ)."""
            w = np.atleast_1d(np.asarray(wear_values, dtype=float))
            white_wear = wear_friction(v[None, :], w[:, None], p) @ whiten.T                 # (Nϖ, N)
            resid = white_tau[None, None, :] - white_nominal[None, :, :] - white_wear[:, None, :]
            return -0.5 * np.einsum("ijk,ijk->ij", resid, resid)

        def neg_log_lik(wear_values: ArrayLike) -> NDArray[np.float64]:
            return -logsumexp(log_weights(wear_values), axis=1)

        grid_cost = neg_log_lik(self._grid_wear)
        k = int(np.argmin(grid_cost))
        lo = self._grid_wear[max(k - 1, 0)]
        hi = self._grid_wear[min(k + 1, self._grid_wear.size - 1)]
        fit = minimize_scalar(lambda w: float(neg_log_lik(w)[0]), bounds=(lo, hi), method="bounded",
                              options={"xatol": 1e-6})
        w_hat = float(fit.x) if fit.fun <= grid_cost[k] else float(self._grid_wear[k])
        info = marginal_fisher_wear(v, w_hat, mu_l, sigma_l, self.noise_std, p, self.temperature_range,
                                    self.n_temperature_samples, friction_stderr=stderr)
        std = math.inf if info <= 0 else 1.0 / math.sqrt(info)
        temperature = None
        if v.size >= 2:  # posterior mean of ξ at ϖ̂
            lw = log_weights(w_hat)[0]
            temperature = float(np.exp(lw - logsumexp(lw)) @ self._xi_samples)
        return WearEstimate(estimate=w_hat, std=std, temperature=temperature, n_points=int(v.size))


class _BadData(Exception):
    def __init__(self, n_points: int, reason: str) -> None:
        super().__init__(reason)
        self.n_points = n_points


def _crlb_std(fisher: NDArray[np.float64]) -> float:
    """``√[F⁻¹]₂₂`` of a 2 × 2 Fisher matrix; inf if singular."""
    det = fisher[0, 0] * fisher[1, 1] - fisher[0, 1] ** 2
    if not np.isfinite(det) or det <= 1e-12 * fisher[0, 0] * fisher[1, 1] or det <= 0.0:
        return math.inf
    return math.sqrt(fisher[0, 0] / det)
