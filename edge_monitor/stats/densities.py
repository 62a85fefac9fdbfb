"""Nominal density models for the decision layer (docs/ALGORITHMS.md §5).

Every model is a finite Gaussian mixture with one shared kernel covariance,
``p0(y) = Σk πk·N(y; μk, S)``, in the units of the monitored quantity (y is d-dimensional).
Builders: :func:`fit_gaussian` (one component), :func:`fit_kde` (one component per datum,
Silverman diagonal bandwidth) and :func:`fit_gce` (Botev–Kroese generalised cross-entropy sparse
mixture); :func:`fit_density` dispatches by name.
"""

from __future__ import annotations

import logging
import math
from typing import Any, Literal

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy import integrate, linalg, optimize

log = logging.getLogger(__name__)

DensityKind = Literal["gauss", "kde", "gce"]
DENSITY_KINDS: tuple[str, ...] = ("gauss", "kde", "gce")
#: Weights whose cumulative sum (smallest first) stays below this are pruned from the GCE mixture.
GCE_PRUNE_EPS = 1e-8
#: Monte Carlo draws for F(0) when d > 1 (fixed seed, so F(0) is reproducible).
FISHER_MC_DRAWS = 20_000
FISHER_MC_SEED = 20_240_601


class DensityError(ValueError):
    """Nominal data unusable for the requested density (too few, constant, non-finite, bad shape)."""


def min_points(kind: str, dim: int) -> int:
    """Smallest nominal sample size accepted for ``kind`` in dimension ``dim``.

    Gaussian: a non-singular covariance needs N0 > d, we ask for d + 2. KDE: Silverman's rule
    needs a spread estimate per axis, we ask for max(5, d + 2). GCE: the bandwidth equation
    Σλ(h) = 1 needs enough pairs to be informative, we ask for max(10, d + 2).
    """
    if kind == "gauss":
        return dim + 2
    if kind == "kde":
        return max(5, dim + 2)
    if kind == "gce":
        return max(10, dim + 2)
    raise DensityError(f"density kind {kind!r} unknown; choose one of {DENSITY_KINDS}")


def as_observations(y: ArrayLike, dim: int | None = None, name: str = "data") -> NDArray[np.float64]:
    """Return ``y`` as a float (n, d) array; 1-D input is n scalar observations (or one
    d-vector when ``dim`` > 1 and the length equals ``dim``)."""
    arr = np.asarray(y, dtype=float)
    if arr.ndim == 0:
        arr = arr.reshape(1, 1)
    elif arr.ndim == 1:
        arr = arr.reshape(1, -1) if (dim is not None and dim > 1 and arr.size == dim) else arr[:, None]
    elif arr.ndim != 2:
        raise DensityError(f"{name}: expected an (n, d) array, got shape {arr.shape}")
    if dim is not None and arr.shape[1] != dim:
        raise DensityError(f"{name}: dimension {arr.shape[1]} does not match the model dimension {dim}")
    return arr


class GaussianMixture:
    """``p0(y) = Σk πk·N(y; μk, S)`` with weights (K,), means (K, d) and shared covariance S (d, d).

    All evaluations are vectorised over observations and components (log-sum-exp). ``whiten`` (L⁻¹, S = LLᵀ)
    and ``log_coef`` (log πk − ½·log|2πS|, (K,)) are what an evaluation uses; a batch of mixtures reads them.
    """

    def __init__(self, weights: ArrayLike, means: ArrayLike, cov: ArrayLike, kind: str = "mixture",
                 fisher: ArrayLike | None = None) -> None:
        w = np.asarray(weights, dtype=float).ravel()
        mu = np.asarray(means, dtype=float)
        mu = mu.reshape(len(w), -1)
        d = mu.shape[1]
        s = np.asarray(cov, dtype=float).reshape(d, d)
        if not (np.all(np.isfinite(w)) and np.all(np.isfinite(mu)) and np.all(np.isfinite(s))):
            raise DensityError("mixture parameters must be finite")
        if np.any(w < 0) or w.sum() <= 0:
            raise DensityError("mixture weights must be non-negative with a positive sum")
        try:
            chol = linalg.cholesky(s, lower=True)
        except linalg.LinAlgError as exc:
            raise DensityError("kernel covariance is not positive definite (constant or collinear "
                               "nominal data?)") from exc
        self.weights = w if abs(w.sum() - 1.0) <= 1e-12 else w / w.sum()
        self.means = mu
        self.cov = s
        self.kind = kind
        self._chol = chol
        self.whiten = linalg.solve_triangular(chol, np.eye(d), lower=True)   # L⁻¹ (whitening)
        self.precision = self.whiten.T @ self.whiten                          # S⁻¹
        self._means_w = mu @ self.whiten.T                                     # L⁻¹μk, (K, d)
        self._means_w_sq = np.einsum("kd,kd->k", self._means_w, self._means_w)
        logdet = 2.0 * np.sum(np.log(np.diag(chol)))
        with np.errstate(divide="ignore"):
            self.log_coef = np.log(self.weights) - 0.5 * (logdet + d * math.log(2.0 * math.pi))   # per component
        self._fisher = None if fisher is None else np.asarray(fisher, dtype=float).reshape(d, d)

    @property
    def dim(self) -> int:
        return int(self.means.shape[1])

    @property
    def n_components(self) -> int:
        return int(self.weights.size)

    @property
    def mean(self) -> NDArray[np.float64]:
        """Mixture mean Σk πk μk, (d,)."""
        return self.weights @ self.means

    @property
    def spread(self) -> NDArray[np.float64]:
        """Standard deviation of the mixture along each axis, (d,): √diag(S + Σk πk μk μkᵀ − μ̄ μ̄ᵀ)."""
        centred = self.means - self.mean
        return np.sqrt(np.diag(self.cov) + self.weights @ (centred * centred))

    def component_logpdf(self, y: ArrayLike) -> NDArray[np.float64]:
        """log(πk·N(yn; μk, S)) for every observation and component, (n, K)."""
        yw = as_observations(y, self.dim) @ self.whiten.T
        quad = (np.einsum("nd,nd->n", yw, yw)[:, None] - 2.0 * (yw @ self._means_w.T)
                + self._means_w_sq[None, :])
        return self.log_coef[None, :] - 0.5 * np.maximum(quad, 0.0)

    def logpdf(self, y: ArrayLike) -> NDArray[np.float64]:
        """log p0(yn), (n,)."""
        lc = self.component_logpdf(y)
        top = lc.max(axis=1)
        return top + np.log(np.exp(lc - top[:, None]).sum(axis=1))

    def responsibilities(self, y: ArrayLike) -> NDArray[np.float64]:
        """Posterior component probabilities ζnk, (n, K); rows sum to 1."""
        lc = self.component_logpdf(y)
        z = np.exp(lc - lc.max(axis=1, keepdims=True))
        return z / z.sum(axis=1, keepdims=True)

    def posterior_mean(self, y: ArrayLike) -> NDArray[np.float64]:
        """Σk ζnk μk, (n, d)."""
        return self.responsibilities(y) @ self.means

    def posterior_mean_and_logpdf(self, y: ArrayLike) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """(Σk ζnk μk (n, d), log p0(yn) (n,)) from one pass over the components."""
        lc = self.component_logpdf(y)
        top = lc.max(axis=1, keepdims=True)
        z = np.exp(lc - top)
        total = z.sum(axis=1, keepdims=True)
        return (z / total) @ self.means, (top + np.log(total))[:, 0]

    def score(self, y: ArrayLike) -> NDArray[np.float64]:
        """∇y log p0(y) = −S⁻¹·(y − Σk ζk μk), (n, d), in 1/units."""
        y2 = as_observations(y, self.dim)
        return -(y2 - self.posterior_mean(y2)) @ self.precision

    def sample(self, n: int, rng: np.random.Generator) -> NDArray[np.float64]:
        """n draws from p0, (n, d)."""
        comp = rng.choice(self.n_components, size=n, p=self.weights)
        return self.means[comp] + rng.standard_normal((n, self.dim)) @ self._chol.T

    def fisher_location(self) -> NDArray[np.float64]:
        """F(0) = E_p0[∇log p0·∇log p0ᵀ], (d, d), per observation, in 1/units².

        Exact (S⁻¹) for one component; adaptive quadrature for d = 1; Monte Carlo with a fixed
        seed (``FISHER_MC_DRAWS``) for d > 1. Computed once and cached.
        """
        if self._fisher is None:
            self._fisher = self._compute_fisher()
        return self._fisher.copy()

    def _compute_fisher(self) -> NDArray[np.float64]:
        if self.n_components == 1:
            return self.precision.copy()
        if self.dim == 1:
            sd = math.sqrt(self.cov[0, 0])
            lo, hi = self.means.min() - 10 * sd, self.means.max() + 10 * sd
            grid = np.linspace(lo, hi, 20_001)
            integrand = np.exp(self.logpdf(grid)) * self.score(grid)[:, 0] ** 2
            return np.array([[float(integrate.simpson(integrand, x=grid))]])
        draws = self.sample(FISHER_MC_DRAWS, np.random.default_rng(FISHER_MC_SEED))
        g = self.score(draws)
        f = g.T @ g / len(g)
        return 0.5 * (f + f.T)

    def state_dict(self) -> dict[str, Any]:
        return {"kind": self.kind, "weights": self.weights.tolist(), "means": self.means.tolist(),
                "cov": self.cov.tolist(),
                "fisher": None if self._fisher is None else self._fisher.tolist()}

    @classmethod
    def from_state(cls, state: dict[str, Any]) -> "GaussianMixture":
        return cls(state["weights"], state["means"], state["cov"], kind=state.get("kind", "mixture"),
                   fisher=state.get("fisher"))


def _check_nominal(y0: ArrayLike, kind: str) -> NDArray[np.float64]:
    arr = as_observations(y0, name="nominal data")
    n, d = arr.shape
    bad = ~np.isfinite(arr)
    if bad.any():
        row, col = np.argwhere(bad)[0]
        raise DensityError(f"nominal data: non-finite value at row {row}, column {col}; "
                           "remove or impute it")
    need = min_points(kind, d)
    if n < need:
        raise DensityError(f"nominal data: {n} point(s) are too few for the {kind!r} density in "
                           f"dimension {d}; provide at least {need}")
    sd = arr.std(axis=0, ddof=1)
    flat = np.flatnonzero(~(sd > 1e-12 * np.maximum(1.0, np.abs(arr).max(axis=0))))
    if flat.size:
        raise DensityError(f"nominal data constant in column(s) {flat.tolist()} (value "
                           f"{arr[0, flat[0]]:g}); a density cannot be fitted to constant data")
    return arr


def fit_gaussian(y0: ArrayLike) -> GaussianMixture:
    """One component: sample mean and covariance (ddof = 1)."""
    arr = _check_nominal(y0, "gauss")
    cov = np.atleast_2d(np.cov(arr, rowvar=False))
    return GaussianMixture([1.0], arr.mean(axis=0, keepdims=True), cov, kind="gauss")


def with_sd_prior(values: ArrayLike, counts: tuple[float, ...], sds: tuple[float, ...]) -> NDArray[np.float64]:
    """Learning values (N0 × d) widened about their mean, per axis with ``counts[i]`` > 0, to the standard deviation
    √(((N0 − 1)·s₀² + k·s²)/(N0 − 1 + k)): the posterior of their variance under a prior of k pseudo-values of
    variance s² (``sds[i]``). A learning window calmer than the quantity's own spread is not taken at its word
    (docs/WITHOUT_MOTOR_TEMPERATURE.md); correlations are kept."""
    arr = np.array(values, dtype=float)
    if not any(counts):
        return arr
    n = arr.shape[0]
    centre, s0 = arr.mean(axis=0), arr.std(axis=0, ddof=1)
    k, prior = np.asarray(counts, dtype=float), np.asarray(sds, dtype=float)
    widened = np.sqrt(((n - 1) * s0 ** 2 + k * prior ** 2) / (n - 1 + k))
    scale = np.where((k > 0) & (s0 > 0), widened / np.where(s0 > 0, s0, 1.0), 1.0)
    return centre + (arr - centre) * scale


def silverman_bandwidth(arr: NDArray[np.float64]) -> NDArray[np.float64]:
    """hi = (4/(d+2))^(1/(d+4))·N0^(−1/(d+4))·σ̂i, (d,), in data units."""
    n, d = arr.shape
    return (4.0 / (d + 2)) ** (1.0 / (d + 4)) * n ** (-1.0 / (d + 4)) * arr.std(axis=0, ddof=1)


def fit_kde(y0: ArrayLike) -> GaussianMixture:
    """One component per datum, πk = 1/N0, S = diag(h²) with Silverman's h."""
    arr = _check_nominal(y0, "kde")
    h = silverman_bandwidth(arr)
    return GaussianMixture(np.full(len(arr), 1.0 / len(arr)), arr, np.diag(h ** 2), kind="kde")


def _gce_weights(sq_dist: NDArray[np.float64], d: int, h: float) -> NDArray[np.float64]:
    """λ(h) = argmin_{λ≥0} λᵀCλ − 2λᵀφ̂ in standardised units (S(h) = h²·I), via NNLS on the
    Cholesky factor: λᵀCλ − 2λᵀφ̂ = ‖Rλ − R⁻ᵀφ̂‖² − const with C = RᵀR."""
    n = sq_dist.shape[0]
    c = (4.0 * math.pi * h * h) ** (-d / 2.0) * np.exp(-sq_dist / (4.0 * h * h))
    k = (2.0 * math.pi * h * h) ** (-d / 2.0) * np.exp(-sq_dist / (2.0 * h * h))
    phi = (k.sum(axis=1) - np.diag(k)) / (n - 1)
    jitter = 1e-10 * c[0, 0]
    for _ in range(8):  # C is near-singular for large h or tied points: add a tiny ridge
        try:
            r = linalg.cholesky(c + jitter * np.eye(n), lower=False)
            break
        except linalg.LinAlgError:
            jitter *= 100.0
    else:  # pragma: no cover - numerically hopeless input
        raise DensityError("GCE: kernel matrix not positive definite even with a ridge")
    rhs = linalg.solve_triangular(r, phi, trans="T", lower=False)
    lam, _ = optimize.nnls(r, rhs, maxiter=50 * n)
    return lam


def fit_gce(y0: ArrayLike, prune_eps: float = GCE_PRUNE_EPS) -> GaussianMixture:
    """Botev–Kroese GCE sparse mixture (docs/ALGORITHMS.md §5).

    Works in standardised coordinates (each column divided by σ̂i), so S(h) = diag(h²σ̂i²). The
    bandwidth h* is the root of Σλ(h) = 1, bracketed by doubling/halving from Silverman's h and
    refined by Brent's method (to 0.1 % in h); Σλ → 0 as h → 0 and → 2^(d/2) as h → ∞, so a bracket always exists.
    """
    arr = _check_nominal(y0, "gce")
    n, d = arr.shape
    sd = arr.std(axis=0, ddof=1)
    x = (arr - arr.mean(axis=0)) / sd
    sq = np.sum((x[:, None, :] - x[None, :, :]) ** 2, axis=-1)

    def excess(log_h: float) -> float:
        return float(_gce_weights(sq, d, math.exp(log_h)).sum() - 1.0)

    lo = math.log(float(silverman_bandwidth(x)[0]))
    f_lo = excess(lo)
    step = math.log(2.0) if f_lo < 0.0 else -math.log(2.0)
    for _ in range(12):  # walk from Silverman's h by factors of 2 until Σλ(h) − 1 changes sign
        hi = lo + step
        f_hi = excess(hi)
        if (f_lo < 0.0) != (f_hi < 0.0):
            break
        lo, f_lo = hi, f_hi
    else:
        raise DensityError("GCE: no bandwidth with Σλ(h) = 1 found (data nearly degenerate); "
                           "use the kde or gauss density")
    log_h = optimize.brentq(excess, min(lo, hi), max(lo, hi), xtol=1e-3)
    h = math.exp(log_h)
    lam = _gce_weights(sq, d, h)
    order = np.argsort(lam)
    drop = order[np.cumsum(lam[order]) < prune_eps]
    keep = np.setdiff1d(np.arange(n), drop)
    log.debug("GCE: h* = %.4g (standardised), %d of %d points kept", h, keep.size, n)
    return GaussianMixture(lam[keep], arr[keep], np.diag((h * sd) ** 2), kind="gce")


def fit_density(y0: ArrayLike, kind: str = "gce") -> GaussianMixture:
    """Fit the nominal density named ``kind`` ("gauss" | "kde" | "gce")."""
    builders = {"gauss": fit_gaussian, "kde": fit_kde, "gce": fit_gce}
    if kind not in builders:
        raise DensityError(f"density kind {kind!r} unknown; choose one of {DENSITY_KINDS}")
    return builders[kind](y0)
