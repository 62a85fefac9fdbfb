"""Maximum-likelihood wear estimation from one cycle's friction data (docs/ALGORITHMS.md §3).

Data: friction data ``τ ∈ R^N`` (dimensionless) at speeds ``|v|`` [rad/s] collected within one
cycle, which share temperature ξ [°C], load and wear ϖ. The controller's load estimate
``τl ~ N(μl, σl²)`` is marginalised (the model is linear in |τl|):

    τ ~ N(τf(v; μl, ξ, ϖ), Σ),   Σ = σ²·I + diag(stderr²) + σl²·s·sᵀ,   s(v) = ∂τf/∂|τl|.

Every call evaluates the whitened cost ``C(ξ, ϖ) = ‖L⁻¹(τ − τf(v; μl, ξ, ϖ))‖²`` (Σ = L·Lᵀ) once on a
grid: ξ at ≥ 100 stratified midpoints of the site range [ξmin, ξmax] (step ≤ 0.25 °C), ϖ in steps
of 0.5 on [0, ϖmax] — one matrix product, since τf = τ0(ξ) + τw(ϖ). From that grid:

* ``method="marginal"`` (the agent's): ϖ̂ = the maximum of the ξ-marginalised likelihood
  ``m(ϖ) = ∫ exp(−C/2) dξ`` (ξ ~ U(ξmin, ξmax)), refined between the neighbours of the best grid
  point by a bounded 1-D search; ξ̂ = posterior mean of ξ at ϖ̂ (``None`` for N = 1). Every N.
* ``method="joint"`` (§3 for N ≥ 2): ``min rᵀΣ⁻¹r`` over ξmin ≤ ξ ≤ ξmax, 0 ≤ ϖ ≤ ϖmax by
  ``scipy.optimize.least_squares`` (trust-region reflective, bounds, analytic Jacobian) from the
  local minima of the grid's profile ``min_ξ C``. Biased low by ≈ 0.6–0.8 std at the design point
  (marginal: 0.35; fold of τ0 in ξ there, docs/WEAR_ESTIMATION.md). N = 1 is always marginal.
* ``std``: the posterior standard deviation of ϖ (flat priors on the box). Not a Cramér–Rao bound:
  the local bound ``[F⁻¹]₂₂`` is not attained away from the design temperature (it is 300–1000 at
  30/50 °C for the 3-point design, where the box on ξ keeps the actual spread near 5), and it
  explodes at ϖ → 0. The Monte Carlo study checks that this std is within 20 % of the spread.
* ``upper_95``: one-sided 95 % upper confidence bound from the profile likelihood: the largest ϖ
  above the profile's minimum with ``min_ξ C(ξ, ϖ) − min C ≤ 1.96²`` (the upper end of the two-sided
  95 % profile-likelihood interval; the nominal one-sided level 1.645² under-covers where the
  estimate is biased low, see ``_PROFILE_THRESHOLD``).
* ``score``: the signed root of the marginal likelihood ratio of the best wear against none,
  ``r = sign(ϖ̃)·√(2·(log m(ϖ̃) − log m(0)))`` with ϖ̃ maximising m over ``[−ϖmax, ϖmax]`` (over
  ``[−20, ϖmax]`` without a temperature prior: ``_FLAT_PRIOR_CONTINUATION``). Below 0 the
  model is continued by the first-order effect of wear, ``τw = ϖ·fvϖ·v`` (what ``wear_friction`` gives
  for ϖ ≤ 0), so that r passes smoothly through ϖ = 0. Without wear r is close to N(0, 1) at every
  temperature (Wilks; measured on healthy simulated joints over 30 … 50 °C: mean 0.0–0.5, std ≈ 1,
  P(r > 3σ) 0.002), while ϖ̂, its std and their ratio all move with how identifiable ϖ is at the
  cycle's temperature. What the wear detector watches (docs/DETECTION.md).
* ``identifiable``: ϖ = 0 lies outside that interval (``min_ξ C(ξ, 0) − min C > 1.96²``). When
  ``False``, publish "ϖ ≤ upper_95", not ϖ̂ ± std: ``∂τf/∂ϖ`` at ϖ → 0 is only ``fvϖ·v`` (the wear
  Stribeck term vanishes faster than any power of ϖ), so low wear cannot be told from none at
  speeds ≫ ϖ·vsϖ.
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass
from typing import Sequence

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.optimize import least_squares, minimize_scalar

from edge_monitor.features.wear_information import (
    _temperature_samples,
    data_covariance,
)
from joint_model.friction import (
    DEFAULT_PARAMS,
    FRICTION_NOISE_STD,
    FrictionParams,
    friction_magnitude,
    jacobian_temperature_wear,
    load_sensitivity,
    nominal_friction,
    wear_friction,
)

log = logging.getLogger(__name__)

#: Likelihood grid: largest temperature step [°C] (the narrowest ξ likelihood met, 12 default speeds,
#: has a std ≥ 0.77 °C, i.e. ≥ 3 steps) and wear step [-] (the std of ϖ̂ is ≥ 3 at every design).
_MAX_TEMPERATURE_STEP = 0.25
#: Speed vectors whose model grids are kept (a robot's test cycle has one; a few after a redesign).
_MODEL_CACHE = 4
_WEAR_STEP = 0.5
#: Profile-likelihood threshold of the upper bound and of the identifiability test: χ²₁(0.95) = 1.96²
#: (the upper end of the two-sided 95 % interval). Calibrated by Monte Carlo: the nominal one-sided
#: 95 % threshold 1.645² covers only 0.93 at the design temperature, where the fold of τ0 in ξ
#: biases the estimates low; 1.96² covers ≥ 0.95 at every design configuration (tools/studies/mc_wear_study.py).
_PROFILE_THRESHOLD = 1.959963984540054 ** 2
#: Local solver starts at most (local minima of the grid's wear profile), ``method="joint"``.
_MAX_STARTS = 3
#: How far below ϖ = 0 the score's first-order continuation reaches when ξ has no prior (flat over the
#: site range): 20 ≈ 4 posterior stds of ϖ̂ on a healthy joint, where it does its job (r continuous through
#: 0). Deeper, a negative wear with a lubricant ≈ 10 °C warmer mimics real wear; the score's sign then
#: flipped from cycle to cycle on a worn joint (wear 20–30: 25 % and 14 % negative, mode at ϖ = −100;
#: bounded: 6 % and 3 %; docs/WEAR_ESTIMATION.md). With a temperature prior ξ is pinned and the
#: continuation keeps the whole mirrored grid.
_FLAT_PRIOR_CONTINUATION = 20.0
_COMPETITIVE_COST = 13.8
_SOLVER_METHOD = "trf"
#: Plausibility limits of the inputs: speeds [rad/s] (useful range ≤ 300), torques (fractions of
#: the joint's maximum torque, |τl| ≤ 0.75). Data beyond them are refused with a reason.
_MAX_PLAUSIBLE_SPEED = 1e4
_MAX_PLAUSIBLE_TORQUE = 10.0


@dataclass(frozen=True)
class WearEstimate:
    """One cycle's wear estimate. ``estimate``/``std``/``upper_95`` in wear units, ``temperature`` in °C.

    ``reason`` is ``None`` for a valid estimate, otherwise why there is none (then ``estimate``,
    ``std`` and ``upper_95`` are NaN). ``std`` is the posterior standard deviation of ϖ (an honest
    spread, checked by Monte Carlo), ``upper_95`` the one-sided 95 % upper confidence bound of ϖ,
    ``identifiable`` whether the data exclude ϖ = 0 (profile likelihood); when it is ``False`` the
    estimate sits where low wear cannot be told from none: report "ϖ ≤ upper_95".
    """

    estimate: float
    std: float
    temperature: float | None
    n_points: int
    reason: str | None = None
    upper_95: float = math.nan
    identifiable: bool = False
    posterior_mean: float = math.nan     # E[ϖ | data] under a flat prior on [0, ϖmax]: continuous near ϖ = 0
    score: float = math.nan              # signed root of the marginal likelihood ratio ϖ̃ vs 0 (≈ N(0, 1) without wear)

    @property
    def ok(self) -> bool:
        return self.reason is None

    @property
    def evidence(self) -> float:
        """Posterior mean over posterior std (dimensionless): how many of its own standard deviations
        the wear sits above none. On a healthy joint it stays put when the temperature moves, while the
        posterior mean and std both grow with temperature as ϖ gets harder to identify (what the wear
        detector watches, docs/DETECTION.md). NaN without a valid estimate."""
        if not (math.isfinite(self.posterior_mean) and math.isfinite(self.std) and self.std > 0):
            return math.nan
        return self.posterior_mean / self.std

    def to_record(self) -> dict[str, float | bool | None]:
        """The ``"wear"`` field of a symptom record (docs/OUTPUTS.md); NaN/inf become ``None``.

        Keys: ``estimate``, ``std``, ``temperature`` (as before) plus ``upper_95`` (one-sided 95 %
        upper bound of ϖ, ``None`` without an estimate) and ``identifiable`` (bool).
        """
        return {"estimate": _json_number(self.estimate), "std": _json_number(self.std),
                "temperature": None if self.temperature is None else _json_number(self.temperature),
                "upper_95": _json_number(self.upper_95), "identifiable": bool(self.identifiable),
                "posterior_mean": _json_number(self.posterior_mean), "evidence": _json_number(self.evidence),
                "score": _json_number(self.score)}


def _json_number(x: float) -> float | None:
    return float(x) if math.isfinite(x) else None


def _invalid(n_points: int, reason: str) -> WearEstimate:
    return WearEstimate(estimate=math.nan, std=math.nan, temperature=None, n_points=n_points, reason=reason)


#: ``"joint"``: docs/ALGORITHMS.md §3 for N ≥ 2 (ML of [ξ, ϖ]); ``"marginal"``: ξ ~ U(range) marginalised for
#: every N (as §3 does for N = 1). See docs/WEAR_ESTIMATION.md for why the second is less biased.
ESTIMATION_METHODS = ("joint", "marginal")


@dataclass(frozen=True)
class _GridSummary:
    """What the (ξ, ϖ) likelihood grid of one cycle says about ϖ (see the module docstring)."""

    mode: float                 # maximum of the ξ-marginalised likelihood
    mean: float                 # posterior mean of ϖ
    std: float                  # posterior std of ϖ
    upper_95: float             # upper end of the profile-likelihood interval
    score: float                # signed root of the marginal likelihood ratio (see the module docstring)
    identifiable: bool          # ϖ = 0 outside the profile-likelihood interval
    temperature: float          # posterior mean of ξ at ``mode``
    profile: NDArray[np.float64]   # min_ξ C(ξ, ϖ) per grid wear
    best_xi: NDArray[np.int64]     # arg min_ξ per grid wear


class WearEstimator:
    """Per-cycle estimator of wear ϖ (and temperature ξ for N ≥ 2) from friction data.

    ``method="joint"`` (default, §3): N ≥ 2 by constrained weighted NLS in [ξ, ϖ].
    ``method="marginal"`` (the agent's): ϖ̂ maximises the ξ-marginalised likelihood, ξ̂ is the
    posterior mean of ξ at ϖ̂. N = 1 is always marginal. Both publish the posterior std, the
    profile-likelihood upper bound and the identifiability flag of the same likelihood grid.
    ``n_temperature_samples`` is the minimum number of ξ grid points (more if the range needs a
    step ≤ 0.25 °C). Stateless between cycles; :meth:`estimate` is deterministic and never raises
    on bad data.
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
        n_xi = max(self.n_temperature_samples, math.ceil((high - low) / _MAX_TEMPERATURE_STEP - 1e-9))
        n_w = max(2, int(math.ceil(self.wear_max / _WEAR_STEP - 1e-9))) + 1
        self._xi_samples = _temperature_samples(self.temperature_range, n_xi)
        self._grid_wear = np.linspace(0.0, self.wear_max, n_w)
        # The score's continuation below ϖ = 0 (mirrors the physical grid; see the module docstring).
        self._grid_signed = np.concatenate([-self._grid_wear[:0:-1], self._grid_wear])
        self._model_cache: dict[bytes, tuple[NDArray[np.float64], ...]] = {}
        # Trapezoid weights of the flat prior of ϖ on [0, ϖmax] (the ξ midpoints carry equal weights).
        self._wear_weights = np.full(n_w, self._grid_wear[1] - self._grid_wear[0])
        self._wear_weights[[0, -1]] *= 0.5

    # ------------------------------------------------------------------ public
    def estimate(self, speeds: Sequence[float] | ArrayLike, friction: Sequence[float] | ArrayLike,
                 load_mean: float, load_std: float,
                 friction_stderr: Sequence[float] | ArrayLike | None = None,
                 temperature_prior: tuple[float, float] | None = None) -> WearEstimate:
        """Estimate ϖ from friction data ``friction`` at ``|speeds|`` [rad/s] of one cycle.

        ``load_mean``/``load_std``: the controller's load estimate and its std (dimensionless).
        ``friction_stderr``: optional per-datum standard errors, added to σ² on the diagonal.
        ``temperature_prior``: (mean, std) [°C] of a Gaussian prior on ξ within the site range (e.g.
        from the motor temperature); ``None``: ξ uniform over the range.
        """
        try:
            checked = self._check(speeds, friction, load_mean, load_std, friction_stderr)
        except _BadData as exc:
            return _invalid(exc.n_points, str(exc))
        v, tau, mu_l, sigma_l, stderr = checked
        try:
            cov = data_covariance(v, sigma_l, self.noise_std, self.params, stderr)
            # N is small (≤ a few tens): the explicit L⁻¹ is cheap and exact enough
            whiten = np.linalg.inv(np.linalg.cholesky(cov))
            cost, white_nominal = self._cost_grid(v, tau, mu_l, whiten)
            if not np.all(np.isfinite(cost)):
                return _invalid(int(v.size), "no finite fit")
            prior = self._prior_cost(temperature_prior)
            grid = self._summarise(cost + prior[:, None], v, whiten, white_nominal, prior)
            if v.size == 1 or self.method == "marginal":
                estimate = grid.mode
                temperature = grid.temperature if v.size >= 2 else None
            else:
                estimate, temperature = self._fit_joint(v, tau, mu_l, whiten, grid)
        except (np.linalg.LinAlgError, ValueError, FloatingPointError, OverflowError) as exc:  # never raise
            log.warning("wear estimation failed: %s", exc)
            return _invalid(int(v.size), f"numerical failure: {exc}")
        return WearEstimate(estimate=estimate, std=grid.std, temperature=temperature, n_points=int(v.size),
                            upper_95=max(grid.upper_95, estimate), identifiable=grid.identifiable,
                            posterior_mean=grid.mean, score=grid.score)

    def _prior_cost(self, prior: tuple[float, float] | None) -> NDArray[np.float64]:
        """−2·log prior(ξ) on the ξ grid (0 for the flat prior), in the units of the cost grid."""
        if prior is None or not (math.isfinite(prior[0]) and math.isfinite(prior[1]) and prior[1] > 0):
            return np.zeros(self._xi_samples.size)
        z = (self._xi_samples - prior[0]) / prior[1]
        return z * z

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

    # -------------------------------------------------------- likelihood grid
    def _cost_grid(self, v, tau, mu_l, whiten) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """``C[i, j] = ‖L⁻¹(τ − τ0(ξi) − τw(ϖj))‖²`` (Nξ × Nϖ, ϖj over the signed grid −ϖmax … ϖmax) by one
        matrix product: ``‖a − b‖² = ‖a‖² + ‖b‖² − 2·a·b`` with a = L⁻¹(τ − τ0(ξi)), b = L⁻¹τw(ϖj).
        Returns (C, a)."""
        unloaded, sensitivity, wear = self._model_at(v)
        a = (tau[None, :] - (unloaded + abs(mu_l) * sensitivity[None, :])) @ whiten.T
        b = wear @ whiten.T
        cost = np.einsum("ik,ik->i", a, a)[:, None] + np.einsum("jk,jk->j", b, b)[None, :] - 2.0 * (a @ b.T)
        return np.maximum(cost, 0.0), a

    def _model_at(self, v: NDArray[np.float64]) -> tuple[NDArray[np.float64], ...]:
        """The model on the grids at the speeds ``v``, which repeat from cycle to cycle (cached): the
        nominal friction without load over the ξ samples (Nξ × n), the load sensitivity s(v) (the
        model is linear in |τl|) and the wear friction over the signed wear grid (Nϖ × n)."""
        key = v.tobytes()
        cached = self._model_cache.get(key)
        if cached is None:
            p = self.params
            cached = (nominal_friction(v[None, :], 0.0, self._xi_samples[:, None], p), load_sensitivity(v, p),
                      wear_friction(v[None, :], self._grid_signed[:, None], p))
            if len(self._model_cache) >= _MODEL_CACHE:
                self._model_cache.pop(next(iter(self._model_cache)))
            self._model_cache[key] = cached
        return cached

    def _summarise(self, signed_cost: NDArray[np.float64], v, whiten, white_nominal,
                   prior: NDArray[np.float64]) -> _GridSummary:
        w = self._grid_wear
        best_signed = np.argmin(signed_cost, axis=0)
        signed_profile = signed_cost[best_signed, np.arange(self._grid_signed.size)]     # min_ξ C
        # log m(ϖ) = −profile/2 + log Σξ exp(−(C − profile)/2): stable, the profile comes for free
        signed_log_m = -0.5 * signed_profile + np.log(
            np.sum(np.exp(-0.5 * (signed_cost - signed_profile[None, :])), axis=0))
        zero = self._grid_signed.size - w.size                  # index of ϖ = 0 on the signed grid
        # ξ pinned by a prior (its cost is not all zero): the whole mirrored grid; flat: bounded below
        floor = 0 if prior.any() else int(np.searchsorted(self._grid_signed, -_FLAT_PRIOR_CONTINUATION))
        top = floor + int(np.argmax(signed_log_m[floor:]))
        score = math.copysign(math.sqrt(max(2.0 * float(signed_log_m[top] - signed_log_m[zero]), 0.0)),
                              float(self._grid_signed[top]))
        best_xi, profile, log_marginal = best_signed[zero:], signed_profile[zero:], signed_log_m[zero:]
        posterior = np.exp(log_marginal - log_marginal.max()) * self._wear_weights
        posterior /= posterior.sum()
        mean = float(posterior @ w)
        std = math.sqrt(max(float(posterior @ (w - mean) ** 2), 0.0))
        mode, xi_weights = self._refine_mode(v, whiten, white_nominal, log_marginal, prior)
        deviance = profile - profile.min()
        upper = _first_crossing(w, deviance, int(np.argmin(profile)), _PROFILE_THRESHOLD)
        temperature = float(xi_weights @ self._xi_samples / xi_weights.sum())
        return _GridSummary(mode=mode, mean=mean, std=std, upper_95=upper, score=score,
                            identifiable=bool(deviance[0] > _PROFILE_THRESHOLD), temperature=temperature,
                            profile=profile, best_xi=best_xi)

    def _refine_mode(self, v, whiten, white_nominal, log_marginal,
                     prior: NDArray[np.float64]) -> tuple[float, NDArray[np.float64]]:
        """Maximum of the exact marginal log-likelihood between the grid neighbours of the best grid
        wear (bounded Brent search), and the ξ posterior weights there."""
        p = self.params

        def weights_and_log_m(wear: float) -> tuple[NDArray[np.float64], float]:
            d = white_nominal - whiten @ wear_friction(v, wear, p)
            c = np.einsum("ik,ik->i", d, d) + prior
            weights = np.exp(-0.5 * (c - c.min()))
            return weights, -0.5 * float(c.min()) + math.log(float(weights.sum()))

        w = self._grid_wear
        k = int(np.argmax(log_marginal))
        lo, hi = w[max(k - 1, 0)], w[min(k + 1, w.size - 1)]
        fit = minimize_scalar(lambda x: -weights_and_log_m(float(x))[1], bounds=(lo, hi), method="bounded",
                              options={"xatol": 1e-6})
        mode = float(fit.x) if -fit.fun >= log_marginal[k] else float(w[k])
        return mode, weights_and_log_m(mode)[0]

    # ------------------------------------------------------------------ joint
    def _fit_joint(self, v, tau, mu_l, whiten, grid: _GridSummary) -> tuple[float, float]:
        """Constrained NLS in [ξ, ϖ] (§3) from the grid's starts; returns (ϖ̂, ξ̂)."""
        p = self.params

        def residual(theta: NDArray[np.float64]) -> NDArray[np.float64]:
            return whiten @ (tau - friction_magnitude(v, mu_l, theta[0], theta[1], p))

        def jacobian(theta: NDArray[np.float64]) -> NDArray[np.float64]:
            return -whiten @ jacobian_temperature_wear(v, theta[0], theta[1], p)

        low = np.array([self.temperature_range[0], 0.0])
        high = np.array([self.temperature_range[1], self.wear_max])
        best_theta, best_cost = None, math.inf
        for start in self._grid_starts(grid):
            x0 = np.clip(start, low, high)
            fit = least_squares(residual, x0, jac=jacobian, bounds=(low, high), method=_SOLVER_METHOD,
                                xtol=1e-8, ftol=1e-10, gtol=1e-10, max_nfev=50)
            for theta, cost in ((fit.x, fit.cost), (x0, 0.5 * float(np.sum(residual(x0) ** 2)))):
                if cost < best_cost:  # never worse than a grid start
                    best_theta, best_cost = theta, cost
        if best_theta is None or not np.isfinite(best_cost):
            raise ValueError("no finite fit")
        return float(best_theta[1]), float(best_theta[0])

    def _grid_starts(self, grid: _GridSummary) -> list[NDArray[np.float64]]:
        """Starts (ξ, ϖ): the best ξ at each local minimum of the grid's wear profile
        ``min_ξ C(ξ, ϖ)``, best first, at most ``_MAX_STARTS``. Several starts are needed because
        the model is flat in ϖ near 0 (a local solver started there stays there)."""
        profile = grid.profile
        padded = np.concatenate([[np.inf], profile, [np.inf]])
        minima = np.flatnonzero((profile <= padded[:-2]) & (profile <= padded[2:]))
        minima = minima[np.argsort(profile[minima], kind="stable")][:_MAX_STARTS]
        # Other minima only if competitive: within a χ²(2) 99.9 % margin (13.8) of the best grid cost.
        minima = minima[profile[minima] <= profile[minima[0]] + _COMPETITIVE_COST]
        return [np.array([self._xi_samples[grid.best_xi[j]], self._grid_wear[j]]) for j in minima]


def _first_crossing(x: NDArray[np.float64], y: NDArray[np.float64], start: int, level: float) -> float:
    """Smallest x ≥ x[start] where y (≤ level at ``start``) rises above ``level``, linearly
    interpolated; ``x[-1]`` if it never does."""
    above = np.flatnonzero(y[start:] > level)
    if above.size == 0:
        return float(x[-1])
    j = start + int(above[0])
    if j == 0:
        return float(x[0])
    return float(np.interp(level, [y[j - 1], y[j]], [x[j - 1], x[j]]))


class _BadData(Exception):
    def __init__(self, n_points: int, reason: str) -> None:
        super().__init__(reason)
        self.n_points = n_points
