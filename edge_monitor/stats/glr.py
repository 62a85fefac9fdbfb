"""Generalised likelihood ratio tests for a bias change (docs/ALGORITHMS.md §6).

H0: y ~ p0, H1: y ~ p0(y − Δ) with Δ unknown. The statistic is
``s(t:n) = Σ_{j=t..n} log[p0(yj − Δ̂) / p0(yj)]`` (dimensionless, natural log). The threshold on s
comes from the false-alarm probability Pf of one test, ``h = ½·χ²_d quantile(1 − Pf)``, and the
estimated miss probability is ``Pm = P(χ'²_d(λ) ≤ 2h)`` with ``λ = ñ·Δ̂ᵀF(0)Δ̂``: F(0) is the
per-observation Fisher information for location, so the segment of ñ observations carries ñ·F(0)
(the docs/ALGORITHMS.md λ = ΔᵀF(0)Δ with F(0) of the whole segment).

* :func:`glr_known_change` — batch test of a segment that starts at the change (EM estimate).
* :func:`glr_unknown_change` — batch test, maximum over candidate change times (EM per candidate).
* :class:`WindowedGLR` — sequential window-limited GLR: candidates among the last W observations,
  SA-EM estimate per candidate, numerator exact over a ring buffer or accumulated recursively.
* :func:`bootstrap_threshold` — a threshold calibrated on the nominal data (finite-sample
  alternative to the asymptotic χ² threshold for the batch test).
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, field
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy import stats

from edge_monitor.stats.bias_em import SAStep, check_gain, check_step, em_bias
from edge_monitor.stats.densities import GaussianMixture, as_observations
from edge_monitor.stats.glr_batch import BatchWindowedGLR, GLRMode, MixtureBatch

#: Largest window [observations]: memory and time per observation are O(window).
MAX_WINDOW = 10_000


class GLRError(ValueError):
    """Invalid GLR settings or input (names the parameter and its valid range)."""


def check_pf(pf: float) -> float:
    """Return ``pf`` as float if it lies in (0, 1), else raise :class:`GLRError`."""
    try:
        value = float(pf)
    except (TypeError, ValueError) as exc:
        raise GLRError(f"pf = {pf!r} is not a number; give a false-alarm probability in (0, 1)") from exc
    if not 0.0 < value < 1.0:
        raise GLRError(f"pf = {pf!r} must lie strictly between 0 and 1 (e.g. 0.01)")
    return value


def threshold_from_pf(pf: float, dim: int) -> float:
    """h(Pf) = ½·χ²_d quantile at 1 − Pf (d = 1, Pf = 0.01: 3.317; d = 2: 4.605)."""
    return 0.5 * float(stats.chi2.isf(check_pf(pf), dim))


def miss_probability(delta: ArrayLike, fisher: ArrayLike, threshold: float, n: int = 1) -> float:
    """Pm = P(χ'²_d(λ) ≤ 2h) with λ = n·ΔᵀF(0)Δ (F(0) per observation, n observations). With a null
    box (:class:`WindowedGLR`), pass the part of the shift outside it."""
    d_vec = np.atleast_1d(np.asarray(delta, dtype=float))
    f = np.asarray(fisher, dtype=float).reshape(d_vec.size, d_vec.size)
    lam = max(float(n) * float(d_vec @ f @ d_vec), 0.0)
    if lam == 0.0:
        return float(stats.chi2.cdf(2.0 * threshold, d_vec.size))
    return float(stats.ncx2.cdf(2.0 * threshold, d_vec.size, lam))


@dataclass
class GLRResult:
    """Outcome of a batch GLR test. ``change_index``: 0-based row of the test data where the
    change is estimated to start (0 for the known-change test)."""

    statistic: float
    threshold: float
    alarm: bool
    delta: list[float]
    miss_probability: float
    change_index: int
    n: int

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)


def _log_ratio_sum(obs: NDArray[np.float64], density: GaussianMixture, delta: NDArray[np.float64]) -> float:
    return float(np.sum(density.logpdf(obs - delta) - density.logpdf(obs)))


def _threshold(density: GaussianMixture, pf: float, threshold: float | None) -> float:
    return threshold_from_pf(pf, density.dim) if threshold is None else float(threshold)


def glr_known_change(y: ArrayLike, density: GaussianMixture, pf: float = 0.01,
                     threshold: float | None = None, tol: float = 1e-10) -> GLRResult:
    """GLR of a segment ``y`` (n, d) that starts at the change: s = Σj log p0(yj − Δ̂)/p0(yj)
    with Δ̂ the batch EM estimate. ``threshold`` overrides h(Pf) (e.g. a bootstrap one)."""
    obs = as_observations(y, density.dim, name="test data")
    h = _threshold(density, pf, threshold)
    delta = em_bias(obs, density, tol=tol)
    s = max(_log_ratio_sum(obs, density, delta), 0.0)
    pm = miss_probability(delta, density.fisher_location(), h, n=len(obs))
    return GLRResult(s, h, bool(s >= h), delta.tolist(), pm, 0, len(obs))


def glr_unknown_change(y: ArrayLike, density: GaussianMixture, pf: float = 0.01,
                       window: int | None = None, threshold: float | None = None,
                       tol: float = 1e-10) -> GLRResult:
    """Batch GLR with unknown change time: s̃ = max_t s(t:n) over candidate starts t (all rows,
    or the last ``window`` rows), EM estimate per candidate. Cost O(N·W·K·iterations)."""
    obs = as_observations(y, density.dim, name="test data")
    n = len(obs)
    h = _threshold(density, pf, threshold)
    first = 0 if window is None else max(0, n - int(window))
    base = density.logpdf(obs)
    best = (-math.inf, 0, np.zeros(density.dim))
    for t in range(first, n):
        delta = em_bias(obs[t:], density, tol=tol)
        s = float(np.sum(density.logpdf(obs[t:] - delta) - base[t:]))
        if s > best[0]:
            best = (s, t, delta)
    s, t_hat, delta = best
    s = max(s, 0.0)
    pm = miss_probability(delta, density.fisher_location(), h, n=n - t_hat)
    return GLRResult(s, h, bool(s >= h), delta.tolist(), pm, t_hat, n)


def bootstrap_statistics(y0: ArrayLike, density: GaussianMixture, n_test: int, n_boot: int = 2000,
                         seed: int = 0) -> NDArray[np.float64]:
    """Bootstrap distribution of the known-change GLR statistic under H0, (n_boot,).

    Each draw resamples ``n_test`` test points from the nominal data ``y0`` and shifts them by the
    model's location error on a resampled nominal set (EM estimate of Δ for N0 resampled nominal
    points, minus that of y0 itself: the location uncertainty of a model fitted on N0 points; for
    one Gaussian it is the error of the resampled mean), then computes the statistic against
    ``density``. This captures the two finite-sample effects the
    χ² threshold ignores: the nominal model's location error (makes the asymptotic test liberal by
    a factor of about 1 + N/N0 on the statistic) and kernel smoothing (the variance of a KDE/GCE
    mixture exceeds the data's, which makes it conservative).
    """
    nominal = as_observations(y0, density.dim, name="nominal data")
    if int(n_test) < 1 or int(n_boot) < 1:
        raise GLRError("bootstrap needs n_test ≥ 1 and n_boot ≥ 1")
    rng = np.random.default_rng(seed)
    n0 = len(nominal)
    centre = nominal.mean(axis=0)
    if density.n_components == 1:  # closed form: s = ½·N·(ȳ − μ)ᵀS⁻¹(ȳ − μ), vectorised over draws
        means = nominal[rng.integers(0, n0, (int(n_boot), int(n_test)))].mean(axis=1)
        shifts = nominal[rng.integers(0, n0, (int(n_boot), n0))].mean(axis=1) - centre
        dev = means - shifts - density.means[0]
        return 0.5 * int(n_test) * np.einsum("bi,ij,bj->b", dev, density.precision, dev)
    values = np.empty(int(n_boot))
    reference = em_bias(nominal, density, tol=1e-8, max_iter=200)
    for b in range(int(n_boot)):
        test = nominal[rng.integers(0, n0, int(n_test))]
        shift = em_bias(nominal[rng.integers(0, n0, n0)], density, tol=1e-8, max_iter=200) - reference
        sample = test - shift
        delta = em_bias(sample, density, tol=1e-8, max_iter=200)
        values[b] = max(_log_ratio_sum(sample, density, delta), 0.0)
    return values


def bootstrap_threshold(y0: ArrayLike, density: GaussianMixture, n_test: int, pf: float,
                        n_boot: int = 2000, seed: int = 0) -> float:
    """Threshold of the known-change batch test calibrated on the nominal data: the (1 − Pf)
    quantile of :func:`bootstrap_statistics`. Needs n_boot ≫ 1/Pf (at least 10/Pf is sensible)."""
    pf = check_pf(pf)
    return float(np.quantile(bootstrap_statistics(y0, density, n_test, n_boot, seed), 1.0 - pf))


@dataclass
class GLRDecision:
    """One sequential decision. ``index``: 0-based number of the observation just processed;
    ``change_index``: 0-based observation number of the estimated change time t̂;
    ``segment_length``: ñ = index − change_index + 1."""

    statistic: float
    threshold: float
    alarm: bool
    change_index: int
    delta: list[float]
    miss_probability: float
    index: int
    segment_length: int = field(default=1)

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)


class WindowedGLR:
    """Window-limited sequential GLR with SA-EM estimates (docs/ALGORITHMS.md §6): one detector, the
    case B = 1 of :class:`~edge_monitor.stats.glr_batch.BatchWindowedGLR` (the recursion the threshold
    calibration simulates).

    Each observation opens a candidate change time and updates the SA-EM estimate Δ̂(t:n) of every
    candidate among the last ``window`` observations. ``mode="recursive"`` accumulates
    log p0(yn − Δ̂(t:n)) − log p0(yn) with the estimate available at step n: O(W·K·d) per observation.
    ``mode="exact"`` recomputes each candidate's numerator over the ring buffer with its latest Δ̂:
    O(W²·K·d). Memory O(W·d) plus the mixture's O(K·d), constant in run length. ``threshold``
    overrides h(Pf) (e.g. a calibrated one). ``null_box`` = (lower, upper), each (d,): the shifts H0
    allows (one-sided tests, drift allowance; :mod:`edge_monitor.stats.glr_batch`), default Δ = 0;
    ``clip`` = (lo, hi), each (d,): where observations are winsorised, default not at all.
    """

    def __init__(self, density: GaussianMixture, window: int = 100, pf: float = 0.01,
                 gamma0: float = 0.6, rho: float = 1.0, mode: GLRMode = "exact",
                 step: SAStep = "fisher", threshold: float | None = None,
                 null_box: tuple[ArrayLike, ArrayLike] | None = None,
                 clip: tuple[ArrayLike, ArrayLike] | None = None) -> None:
        if int(window) < 1:
            raise GLRError(f"window = {window!r} must be a positive number of observations (e.g. 100)")
        if mode not in ("exact", "recursive"):
            raise GLRError(f"mode = {mode!r} must be 'exact' or 'recursive'")
        check_gain(gamma0, rho)
        check_step(step)
        self.density = density
        self.window = int(window)
        self.pf = check_pf(pf)
        self.gamma0, self.rho, self.mode, self.step = float(gamma0), float(rho), mode, step
        self.threshold = _threshold(density, self.pf, threshold)
        self._fisher = density.fisher_location()
        self._glr = BatchWindowedGLR(MixtureBatch([density], step), self.window, gamma0, rho, mode,
                                     null_box=_one_row(null_box, density.dim), clip=_one_row(clip, density.dim))

    @property
    def count(self) -> int:
        """Observations taken since the start (or the last :meth:`restart`)."""
        return self._glr.count

    @property
    def latest(self) -> NDArray[np.float64] | None:
        """The last observation taken (d,), winsorised as the recursion holds it (fed again to
        :meth:`update_statistic` it gives the same statistic); None before the first."""
        g = self._glr
        return None if g.count == 0 else g.obs[0, (g.count - 1) % self.window].copy()

    def restart(self) -> None:
        """Forget every observation (the statistic starts from 0); density, threshold, null box and
        winsorisation are kept."""
        g = self._glr
        self._glr = BatchWindowedGLR(g.mix, self.window, self.gamma0, self.rho, self.mode,
                                     null_box=(g.lower, g.upper), clip=(g.clip_lo, g.clip_hi))

    def update_statistic(self, y: ArrayLike) -> float:
        """Process one finite observation (d,) and return only the statistic (no decision; for replays
        of one path against many thresholds)."""
        obs = as_observations(y, self.density.dim, name="observation")[0]
        if not np.all(np.isfinite(obs)):
            raise GLRError("observation must be finite; skip NaN/inf before calling update()")
        return float(self._glr.update(obs[None, :])[0])

    def update(self, y: ArrayLike) -> GLRDecision:
        """Process one finite observation (d,) and return the decision at this step."""
        s = self.update_statistic(y)
        glr = self._glr
        best = int(glr.best[0])
        delta = glr.delta[0, best]
        n_seg = int(glr.segment_length()[0])
        excess = delta - glr.null_shift(delta[None, None, :])[0, 0]
        pm = miss_probability(excess, self._fisher, self.threshold, n=n_seg)
        return GLRDecision(s, self.threshold, bool(s >= self.threshold), int(glr.times[best]),
                           delta.tolist(), pm, glr.count - 1, n_seg)

    def state_dict(self) -> dict[str, Any]:
        g = self._glr
        return {"density": self.density.state_dict(), "window": self.window, "pf": self.pf,
                "gamma0": self.gamma0, "rho": self.rho, "mode": self.mode, "step": self.step,
                "threshold": self.threshold, "count": g.count, "obs": g.obs[0].tolist(),
                "base": g.base[0].tolist(), "times": g.times.tolist(),
                "delta": g.delta[0].tolist(), "recursive_sum": g.sums[0].tolist(),
                "null_box": [_json_bounds(g.lower[0]), _json_bounds(g.upper[0])],
                "clip": [_json_bounds(g.clip_lo[0]), _json_bounds(g.clip_hi[0])]}

    @classmethod
    def from_state(cls, state: dict[str, Any]) -> "WindowedGLR":
        window = int(state["window"])
        if not 1 <= window <= MAX_WINDOW:     # a corrupted size must not allocate gigabytes
            raise GLRError(f"WindowedGLR.from_state: window = {window} outside 1 … {MAX_WINDOW}")
        glr = cls(GaussianMixture.from_state(state["density"]), window, state["pf"],
                  state["gamma0"], state["rho"], state["mode"], state.get("step", "fisher"),
                  threshold=state["threshold"], null_box=_pair_from_json(state.get("null_box")),
                  clip=_pair_from_json(state.get("clip")))
        d, w, g = glr.density.dim, glr.window, glr._glr
        g.count = int(state["count"])
        g.obs[0] = np.asarray(state["obs"], dtype=float).reshape(w, d)
        g.base[0] = np.asarray(state["base"], dtype=float).reshape(w)
        g.times[:] = np.asarray(state["times"], dtype=np.int64).reshape(w)
        g.delta[0] = np.asarray(state["delta"], dtype=float).reshape(w, d)
        g.sums[0] = np.asarray(state["recursive_sum"], dtype=float).reshape(w)
        return glr


def _json_bounds(bounds: NDArray[np.float64]) -> list[float | str]:
    """Bounds for JSON: ±inf as the strings "-inf"/"inf" (JSON has no infinity)."""
    return [float(b) if math.isfinite(b) else ("inf" if b > 0 else "-inf") for b in bounds]


def _pair_from_json(pair: Any) -> tuple[NDArray[np.float64], NDArray[np.float64]] | None:
    if pair is None:
        return None
    return np.array([float(v) for v in pair[0]]), np.array([float(v) for v in pair[1]])


def _one_row(pair: tuple[ArrayLike, ArrayLike] | None, dim: int
             ) -> tuple[NDArray[np.float64], NDArray[np.float64]] | None:
    """(lo, hi) of one detector as the (1, d) rows of the batch recursion."""
    if pair is None:
        return None
    return np.asarray(pair[0], dtype=float).reshape(1, dim), np.asarray(pair[1], dtype=float).reshape(1, dim)
