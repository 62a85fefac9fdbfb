"""The simulated fleet of a Gaussian calibration (steps 1–2 of :mod:`edge_monitor.stats.gaussian_calibration`):
learning sets fitted as the agent fits its own, ``streams`` detectors per fitted nominal, where each
nominal's streams sit (the calibration point; drift draws and their importance weights), the streams'
values in standard units (iid, or with a slow AR(1) wander), and the first cycle each detector's statistic
reaches each threshold of a grid. Public, so that an independent check of the calibration
(tools/studies/arl_check.py) runs the very same fleet with its own seed.
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass
from typing import TYPE_CHECKING, Callable

import numpy as np
from numpy.typing import NDArray
from scipy.stats import norm

from edge_monitor.stats.glr_gaussian import GaussianBatchGLR
from edge_monitor.stats.learning_error import TILTS as FIT_TILTS
from edge_monitor.stats.normalising_transform import YeoJohnson, yeo_johnson

if TYPE_CHECKING:
    from edge_monitor.stats.gaussian_calibration import GaussianSettings

#: Seed of every Gaussian calibration: the draws are the same for every detector and path.
SEED = 20261126
#: Cycles simulated between first-passage updates.
SEGMENT = 2000
#: Lag-1 coefficient of the slow wander's AR(1) component (``GaussianSettings.wander``): fitted to the
#: variance ratios k·var(k-cycle mean)/var = 1.19, 1.32, 1.39 at k = 5, 10, 30 of the log KL distances
#: of 48 warm healthy joints (docs/DETECTION.md).
WANDER_COEFFICIENT = 0.7


def fit_nominals(samples: NDArray[np.float64]) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Means (G, d) and covariances (G, d, d; ddof = 1) of nominal sets ``samples`` (G, N0, d), as the
    agent fits its own."""
    means = samples.mean(axis=1)
    dev = samples - means[:, None, :]
    return means, np.einsum("gni,gnj->gij", dev, dev) / (samples.shape[1] - 1)


def fleet_detectors(settings: GaussianSettings, means: NDArray[np.float64], covs: NDArray[np.float64],
                    streams: int) -> GaussianBatchGLR:
    """``streams`` detectors for each fitted nominal (means (G, d), covariances (G, d, d))."""
    sd = np.sqrt(np.diagonal(covs, axis1=1, axis2=2))
    upper = settings.allowance * sd
    lower = np.full_like(upper, -np.inf) if settings.direction == "increase" else -upper
    if settings.clip_sigma:
        clip = (means - settings.clip_sigma * sd, means + settings.clip_sigma * sd)
    else:
        clip = (np.full_like(sd, -np.inf), np.full_like(sd, np.inf))
    rep = functools.partial(np.repeat, repeats=streams, axis=0)
    return GaussianBatchGLR(rep(means), rep(covs), settings.window, settings.gamma0, settings.rho,
                            (rep(lower), rep(upper)), (rep(clip[0]), rep(clip[1])))


def stream_shifts(settings: GaussianSettings, nominals: int, d: int, tilts: tuple[float, ...] = (0.0,)
                  ) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Where each nominal's streams sit (nominals × d), in standard units, and the importance weight of
    that draw (nominals,) (step 2 of the gaussian_calibration module docstring)."""
    ones = np.ones(nominals)
    if settings.at == "boundary":
        return np.full((nominals, d), settings.allowance), ones
    if settings.at != "healthy_drift":
        return np.zeros((nominals, d)), ones
    z, weight = drift_draws(nominals, tilts)
    mean = np.broadcast_to(np.asarray(settings.drift_mean or (0.0,), dtype=float), (d,))
    sd = np.broadcast_to(np.asarray(settings.drift_sd or (0.0,), dtype=float), (d,))
    return mean[None, :] + z[:, None] * sd[None, :], weight


def pairing(tilts: tuple[float, ...]) -> int:
    """The nominals over which every pair of the learning error's and the drift's proposals is drawn once."""
    return len(FIT_TILTS) * len(tilts)


def drift_draws(nominals: int, tilts: tuple[float, ...] = (0.0,)) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """The drift draw z of each nominal and its importance weight: nominal g draws from proposal
    N(t_k, 1), k = ⌊g / 4⌋ mod K, as the stratified quantiles of that proposal in a fixed random order;
    weights φ(z)/mean_k φ(z − t_k), mean ≈ 1 (all 1 for the plain draws, ``tilts`` (0,)). The learning
    error's proposal is g mod 4 (:data:`~edge_monitor.stats.learning_error.TILTS`), so every pair of
    the two proposals is drawn equally often and the two weights multiply."""
    rng = np.random.default_rng([SEED, 3])
    t = np.asarray(tilts, dtype=float)
    component = (np.arange(nominals) // len(FIT_TILTS)) % t.size
    z = np.empty(nominals)
    for k in range(t.size):
        members = np.flatnonzero(component == k)
        z[members] = t[k] + rng.permutation(norm.ppf((np.arange(members.size) + 0.5) / members.size))
    if not np.any(t):
        return z, np.ones(nominals)
    log_mixture = np.logaddexp.reduce(norm.logpdf(z[:, None] - t[None, :]), axis=1) - math.log(t.size)
    return z, np.exp(norm.logpdf(z) - log_mixture)


#: Smallest spread a spread law's draw takes [learned standard deviations].
MIN_SPREAD = 0.05


def spread_draws(mean: float, sd: float, index: NDArray[np.int64], key: tuple[int, ...] = ()
                 ) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Each nominal's stream spread under a spread law N(``mean``, ``sd``) [learned standard deviations] and its
    importance weight: nominal ``index[g]`` draws z' from proposal N(t_k, 1), k = index mod len(TILTS) of the
    learning error's :data:`~edge_monitor.stats.learning_error.TILTS` (the slot a law in learned units leaves
    free: the widest joints decide a deep threshold), spread max(mean + sd·z', :data:`MIN_SPREAD`), weight
    φ(z')/mean_k φ(z' − t_k). The draws' seed: ``index[0]`` and ``key`` (one per chunk and stream of draws)."""
    rng = np.random.default_rng([SEED, 4, int(index[0]) if index.size else 0, *key])
    t = np.asarray(FIT_TILTS, dtype=float)
    z = rng.standard_normal(index.size) + t[index % t.size]
    log_mixture = np.logaddexp.reduce(norm.logpdf(z[:, None] - t[None, :]), axis=1) - math.log(t.size)
    return np.maximum(mean + sd * z, MIN_SPREAD), np.exp(norm.logpdf(z) - log_mixture)


def skew_normal_standard(alpha: float | NDArray[np.float64], normals: NDArray[np.float64],
                         halves: NDArray[np.float64]) -> NDArray[np.float64]:
    """Skew-normal values of shape ``alpha`` (Azzalini; one shape, or one per axis of the last dimension)
    standardised to mean 0 and variance 1, from two arrays of standard normal draws of one shape: δ·|h| +
    √(1 − δ²)·n, δ = α/√(1 + α²), less its mean δ·√(2/π), over its sd √(1 − 2δ²/π). α < 0 skews to the left: a
    lighter upper tail than the Gaussian's; α = 0 gives ``normals`` back."""
    a = np.asarray(alpha, dtype=float)
    delta = a / np.sqrt(1.0 + a * a)
    mean = delta * math.sqrt(2.0 / math.pi)
    return (delta * np.abs(halves) + np.sqrt(1.0 - delta * delta) * normals - mean) / np.sqrt(1.0 - mean * mean)


class StreamNoise:
    """Values in standard units with correlation R across axes: iid, or with a slow AR(1) wander
    carrying ``wander`` of each axis's variance (step 2 of the gaussian_calibration module docstring); the iid
    part skew-normal of shape ``skew`` if given, one per axis (0: Gaussian; the wander stays Gaussian)."""

    def __init__(self, lower_chol: NDArray[np.float64], wander: tuple[float, ...], rng: np.random.Generator,
                 skew: tuple[float, ...] = ()) -> None:
        d = lower_chol.shape[0]
        self.chol, self.rng = lower_chol, rng
        f = np.broadcast_to(np.asarray(wander or (0.0,), dtype=float), (d,))
        self.slow, self.fast = np.sqrt(f), np.sqrt(1.0 - f)
        self.wanders = bool(np.any(f > 0))
        self.phi = WANDER_COEFFICIENT
        self.state: NDArray[np.float64] | None = None
        if skew and len(skew) != d:
            raise ValueError(f"a skewed stream needs one shape per axis ({d}); a scalar takes one, got {skew!r}")
        self.skew = np.asarray(skew, dtype=float) if any(skew) else None

    def _draw(self, shape: tuple[int, ...]) -> NDArray[np.float64]:
        return self.rng.standard_normal((*shape, self.chol.shape[0])) @ self.chol.T

    def _draw_iid(self, shape: tuple[int, ...]) -> NDArray[np.float64]:
        """The iid part: Gaussian, or skew-normal of shape ``skew`` (unit variance either way)."""
        if self.skew is None:
            return self._draw(shape)
        return skew_normal_standard(self.skew, self._draw(shape), self._draw(shape))

    def start(self, b: int) -> None:
        """``b`` streams, their wander drawn from its stationary law."""
        self.state = self._draw((b,)) if self.wanders else None

    def step(self, b: int) -> NDArray[np.float64]:
        """The next value of each of the ``b`` streams (b, d)."""
        if self.state is None:
            return self._draw_iid((b,))
        self.state = self.phi * self.state + math.sqrt(1.0 - self.phi ** 2) * self._draw((b,))
        return self.fast * self._draw_iid((b,)) + self.slow * self.state

    def sequence(self, g: int, n: int) -> NDArray[np.float64]:
        """``g`` sequences of ``n`` consecutive values (g, n, d): learning sets."""
        if not self.wanders:
            return self._draw((g, n))
        self.start(g)
        return np.stack([self.step(g) for _ in range(n)], axis=1)


@dataclass(frozen=True)
class LearnedTransforms:
    """Per scalar nominal (G,): the Yeo–Johnson transform its detector learned, z = YJ((y − center)/scale; lam),
    and the Gaussian it fitted to its transformed learning values (``z_mean``, ``z_var`` with ddof = 1), as
    :class:`~edge_monitor.stats.sequential_detector.SequentialDetector` learns its steady nominal."""

    center: NDArray[np.float64]
    scale: NDArray[np.float64]
    lam: NDArray[np.float64]
    z_mean: NDArray[np.float64]
    z_var: NDArray[np.float64]

    @classmethod
    def fit(cls, samples: NDArray[np.float64], center: NDArray[np.float64] | None = None,
            scale: NDArray[np.float64] | None = None) -> "LearnedTransforms":
        """Fit each learning set of ``samples`` (G, N0). ``center``/``scale`` (G,): the learning sets' mean and
        sd drawn elsewhere (the fit's exact law); ``samples`` then give only each set's standardised shape,
        which for Gaussian values is independent of its mean and sd (Basu's theorem), so λ̂ and the fitted
        Gaussian of the transformed values are exactly those of a set with that mean and sd."""
        fits = [YeoJohnson.fit(row) for row in samples]
        z = np.stack([f.apply(row[:, None])[:, 0] for f, row in zip(fits, samples)])   # as the agent transforms
        own = {k: np.array([float(getattr(f, k)[0]) for f in fits]) for k in ("center", "scale", "lambdas")}
        return cls(own["center"] if center is None else np.asarray(center, dtype=float),
                   own["scale"] if scale is None else np.asarray(scale, dtype=float),
                   own["lambdas"], z.mean(axis=1), z.var(axis=1, ddof=1))

    def repeat(self, streams: int) -> "LearnedTransforms":
        """Each nominal's transform for its ``streams`` detectors (G·streams,)."""
        rep = functools.partial(np.repeat, repeats=streams)
        return LearnedTransforms(rep(self.center), rep(self.scale), rep(self.lam), rep(self.z_mean), rep(self.z_var))

    def apply(self, y: NDArray[np.float64]) -> NDArray[np.float64]:
        """Transformed values (B, 1) of one value per detector ``y`` (B, 1)."""
        return yeo_johnson((y[:, 0] - self.center) / self.scale, self.lam)[:, None]


def first_passages(glr: GaussianBatchGLR, shift: NDArray[np.float64], noise: StreamNoise, steps: int,
                   grid: NDArray[np.float64],
                   observe: Callable[[NDArray[np.float64]], NDArray[np.float64]] | None = None,
                   scale: NDArray[np.float64] | None = None) -> NDArray[np.int64]:
    """First cycle (0-based) each detector's statistic reaches each grid threshold, ``steps`` if never;
    detector b's stream scaled by ``scale[b]`` (a spread law, if given), moved by ``shift[b]`` (standard
    units) and seen through ``observe`` (a learned transform) if given."""
    b, d = glr.means.shape
    noise.start(b)
    first = np.full((b, grid.size), steps, dtype=np.int64)
    running = np.zeros(b)
    for start in range(0, steps, SEGMENT):
        length = min(SEGMENT, steps - start)
        stats = np.empty((b, length))
        for t in range(length):
            y = noise.step(b) if scale is None else scale * noise.step(b)
            y = y + shift
            stats[:, t] = glr.update(y if observe is None else observe(y))
        stats[:, 0] = np.maximum(stats[:, 0], running)
        np.maximum.accumulate(stats, axis=1, out=stats)
        running = stats[:, -1]
        reached = np.stack([np.searchsorted(row, grid, side="left") for row in stats])
        first = np.where((first == steps) & (reached < length), start + reached, first)
    return first
