"""Thresholds of Gaussian-nominal detectors: exact to a stated Monte Carlo error, reproducible, fast.

A detector with a Gaussian nominal N(μ̂, Ŝ), its null box and its winsorising range (all set in
standard deviations of the values it learned) is invariant to the location and scale of each axis:
in standard units z = (y − μ̂)/σ̂ its statistic's law depends only on the settings and, for d > 1, on the
correlation matrix R of the learned values. So the calibration simulates in standard units, from
N(0, R) with a fixed seed (:data:`SEED`): the same settings and R give the same threshold on every
path and machine, and for d = 1 the threshold is one number per setting (cached, and tabulated for the
shipped settings, :mod:`edge_monitor.stats.threshold_table`). The detectors run the closed-form
recursion of :class:`~edge_monitor.stats.glr_gaussian.GaussianBatchGLR` (≈ 1 µs per detector and
cycle in d = 1), so many more can be simulated than with a general mixture:

1. ``nominals`` nominal sets of N0 values from N(0, R), each fitted (mean, covariance with ddof = 1,
   its null box and winsorising range) as the agent fits its own — the learning error. For a detector
   with independent learning values the fit is drawn from its exact law instead (the mean
   √N0·μ̂ ~ N(0, 1), the spread (N0 − 1)·σ̂² ~ χ²(N0 − 1); for d > 1 the whitened mean ~ N(0, I) and
   (N0 − 1)·Σ̂ ~ Wishart(N0 − 1, R)), by importance sampling (:func:`scalar_fits`, :func:`vector_fits`):
   the fleet's rate at a high threshold is decided by the few nominals learned too low and too narrow,
   which plain draws of a few thousand learning sets hardly ever hold. A scalar detector that learns a
   Yeo–Johnson transform first (``GaussianSettings.transform``, the steady stage) has its exponent fitted
   to a plain standard normal set standing for the learning set's standardised shape (independent of its
   mean and spread for Gaussian values), its Gaussian fitted to the transformed set, and its streams seen
   through the transform (:class:`~edge_monitor.stats.gaussian_fleet.LearnedTransforms`);
2. ``streams`` detectors per nominal on independent streams from N(0, R) moved by the calibration
   point (``"nominal"``: not at all; ``"boundary"``: ``allowance`` standard deviations up;
   ``"healthy_drift"``: nominal g's streams by ``drift_mean + drift_sd·z_g`` standard deviations, z_g the
   stratified normal quantiles in a fixed random order — a fleet whose joints drift after learning; with
   ``GaussianBudget.drift_tilts`` drawn from proposal N(t_k, 1), k = ⌊g/4⌋ mod K (``drift_draws``), and
   weighted by φ(z)/mean_k φ(z − t_k) (the balance heuristic): a deep-tail threshold is decided by the
   few joints that drift furthest, which plain draws hardly hold),
   ``steps`` cycles each; with ``wander`` (per axis, a fraction f of the variance), each value is
   √(1 − f)·e + √f·a with a a unit AR(1) process of coefficient
   :data:`~edge_monitor.stats.gaussian_fleet.WANDER_COEFFICIENT` — the slow wander of a warm joint's
   quantities, which makes consecutive values, learning sets included, dependent (steps 1–2 run the fleet
   of :mod:`edge_monitor.stats.gaussian_fleet`);
3. per nominal g and candidate threshold h its false-alarm rate from its first passages (e/X, events
   over exposure; (e − 1)/X when no stream was censored), and the fleet's run length 1/mean_g(w_g·rate)
   with w_g the nominal's importance weight (1 where its learning set was drawn as it is);
4. h where that run length is the target: interpolated between grid thresholds whose alarms are worth at
   least :data:`MIN_EVENTS_DIRECT` unweighted ones ((Σ w·e)² / Σ w²·e, Kish's effective count; with
   weights it need not fall monotonically with h, so each grid threshold is judged on its own), else
   extrapolated along log E[T] = a + c·h over the last nat of those;
5. its precision: the standard error of h from a bootstrap over the nominals (both the learning
   error and the Monte Carlo error), reported with the threshold.
"""

from __future__ import annotations

import functools
import logging
import math
import time
from dataclasses import dataclass, replace

import numpy as np
from numpy.typing import NDArray

from edge_monitor.stats.gaussian_fleet import (  # noqa: F401  (WANDER_COEFFICIENT: re-exported)
    SEED,
    WANDER_COEFFICIENT,
    LearnedTransforms,
    StreamNoise,
    first_passages,
    fit_nominals,
    fleet_detectors,
    pairing,
    spread_draws,
    stream_shifts,
)
from edge_monitor.stats.learned_axes import independent_learned_axes, partly_learned_fits, proposal_sets
from edge_monitor.stats.learning_error import scalar_fits, vector_fits

log = logging.getLogger(__name__)

#: A correlation matrix as nested tuples (hashable: simulations are cached per matrix).
Correlation = tuple[tuple[float, ...], ...]

#: Threshold grid step [nats].
H_STEP = 0.025
#: Alarmed detectors a threshold needs to be read off directly (else extrapolated).
MIN_EVENTS_DIRECT = 30
#: Bootstrap resamples of the nominals for the standard error of h.
BOOTSTRAP = 200
#: Detectors simulated at once (larger batches fall out of the CPU caches).
CHUNK = 512
#: Top of the threshold grid [nats].
H_MAX = 60.0
#: Importance sampling of the healthy drift (``GaussianBudget.drift_tilts``; the table's wide-drift entries,
#: and a run-time calibration whose target plain draws do not reach): the proposals' shifts of the drift
#: draw z. At one false alarm per robot-year (ARL0 ≈ 2.6·10⁶) kl_weighted's steady rate comes from joints
#: drifting z > 2 of the drift law's standard deviations up (64 % from z > 3, just past the allowance),
#: ≈ 2 % of the plain draws (docs/DETECTION.md, "Deep-tail thresholds").
DRIFT_TILTS = (0.0, 1.5, 3.0, 4.5)


@dataclass(frozen=True)
class GaussianSettings:
    """What a Gaussian detector's threshold depends on besides R and the target (see the module docstring)."""

    n0: int
    window: int
    gamma0: float
    rho: float
    direction: str
    allowance: float
    clip_sigma: float
    at: str                        # "nominal" | "boundary" | "healthy_drift"
    drift_mean: tuple[float, ...] = ()     # "healthy_drift": each nominal's streams moved by drift_mean +
    drift_sd: tuple[float, ...] = ()       # drift_sd·z (standard units, one z per nominal, per axis)
    wander: tuple[float, ...] = ()         # per axis: the variance fraction of the slow AR(1) wander
    transform: str = "none"                # "yeo-johnson": a scalar detector that learns this transform before
                                           # its Gaussian, its exponent's learning error simulated too
    spread_mean: tuple[float, ...] = ()    # "healthy_drift" in learned units (a scalar): each nominal's streams
    spread_sd: tuple[float, ...] = ()      # have spread spread_mean + spread_sd·z' and sit at drift_mean +
                                           # drift_sd·z in the nominal's learned units (with ``wander`` in their
                                           # values, not in a learning set), no learning error drawn; a vector:
                                           # one per axis, spread_mean 0 where an axis keeps its learning error
    skew: tuple[float, ...] = ()           # with a spread law: the skew-normal shape α of the values' iid part

    def __post_init__(self) -> None:
        if not any(self.wander):               # no wander on any axis: one setting, one table key
            object.__setattr__(self, "wander", ())
        if not any(self.skew):                 # Gaussian values: the key of before
            object.__setattr__(self, "skew", ())
        if self.transform not in ("none", "yeo-johnson"):
            raise ValueError(f"transform = {self.transform!r}; choose 'none' or 'yeo-johnson'")
        law = self.spread_mean or self.spread_sd
        if law and (self.at != "healthy_drift" or len(self.spread_mean) != len(self.spread_sd)
                    or self.transform != "none" or (len(self.spread_mean) > 1 and any(self.wander))
                    or not all(m == 0 or 0.05 <= m <= 5 for m in self.spread_mean) or not any(self.spread_mean)
                    or not all(0 <= sd < math.inf for sd in self.spread_sd)
                    or any(sd and not m for m, sd in zip(self.spread_mean, self.spread_sd))):
            raise ValueError("a spread law (the healthy drift in learned units) is for a warm-up detector calibrated "
                             "at the healthy drift, without a transform: one spread mean (0.05 … 5; a vector's axis "
                             "0 where it keeps its learning error) and sd (≥ 0, 0 with mean 0) per axis (a vector: "
                             f"without wander), got {self.spread_mean!r}, {self.spread_sd!r}")
        if self.skew and (len(self.skew) != len(self.spread_mean)
                          or any(a and not m for a, m in zip(self.skew, self.spread_mean))):
            raise ValueError("a skew (one skew-normal shape per axis of the spread law, 0 where an axis has none) is "
                             "simulated with a spread law only")

    @property
    def in_learned_units(self) -> bool:
        """Whether the healthy joint is drawn in its nominal's learned units (a scalar's spread law is given): the
        drift and spread measured there already hold the nominal's learning error, which is then not drawn again."""
        return len(self.spread_mean) == 1

    @property
    def learned_axes(self) -> tuple[int, ...]:
        """A vector's axes drawn in learned units, as a scalar's (their spread law's mean > 0); its other axes keep
        their learning error and drift."""
        return tuple(i for i, s in enumerate(self.spread_mean) if s > 0) if len(self.spread_mean) > 1 else ()


@dataclass(frozen=True)
class GaussianBudget:
    """``nominals`` × ``streams`` simulated detectors of ``steps`` cycles each."""

    nominals: int = 256
    streams: int = 4
    steps: int = 2000
    #: "healthy_drift": the proposals' tilts of the drift draw z (standard normal units); (0,): plain draws
    drift_tilts: tuple[float, ...] = (0.0,)

    def __post_init__(self) -> None:
        tilts = self.drift_tilts
        if not tilts or 0.0 not in tilts or not all(math.isfinite(t) for t in tilts):
            raise ValueError(f"drift_tilts must be finite and hold 0 (the weights are then at most their number), "
                             f"got {tilts!r}")
        if any(tilts) and self.nominals % pairing(tilts) != 0:
            raise ValueError(f"with drift tilts the nominals must be a multiple of {pairing(tilts)} (every pair "
                             f"of the learning error's and the drift's proposals drawn equally often), "
                             f"got {self.nominals}")

    def tilted(self, tilts: tuple[float, ...] = DRIFT_TILTS) -> "GaussianBudget":
        """This budget with the drift importance-sampled, its nominals rounded up to whole :func:`pairing` s."""
        return replace(self, nominals=-(-self.nominals // pairing(tilts)) * pairing(tilts), drift_tilts=tuple(tilts))

    def reaches(self, arl0: float) -> bool:
        """Whether plain draws can read a threshold for ``arl0`` off directly: the simulated detector-cycles
        hold :data:`MIN_EVENTS_DIRECT` false alarms at that run length."""
        return self.nominals * self.streams * self.steps >= MIN_EVENTS_DIRECT * arl0


@dataclass(frozen=True)
class GaussianThreshold:
    """h [nats] for mean run length ``arl0`` [cycles], its bootstrap standard error ``h_se`` [nats], how it
    was read (``"simulated"`` | ``"extrapolated"``), the detectors that alarmed at h, the simulated
    detectors and cycles, and the CPU time it took [s]."""

    threshold: float
    h_se: float
    arl0: float
    method: str
    events: int
    detectors: int
    steps: int
    cpu_s: float


def correlation(values: NDArray[np.float64]) -> Correlation:
    """The correlation matrix of learned values (N0 × d) as nested tuples (d = 1: ((1.0,),))."""
    if values.shape[1] == 1:
        return ((1.0,),)
    r = np.atleast_2d(np.asarray(np.corrcoef(values, rowvar=False), dtype=float))
    r = (r + r.T) / 2.0
    np.fill_diagonal(r, 1.0)
    return tuple(tuple(float(x) for x in row) for row in r)


def threshold(settings: GaussianSettings, corr: Correlation, arl0: float,
              budget: GaussianBudget = GaussianBudget()) -> GaussianThreshold:
    """The threshold for ``arl0`` (see the module docstring). The simulation is cached per settings,
    correlation and budget: every target of one detector family costs one simulation."""
    return thresholds(settings, corr, (arl0,), budget)[0]


def thresholds(settings: GaussianSettings, corr: Correlation, targets: tuple[float, ...],
               budget: GaussianBudget = GaussianBudget(), progress: bool = False) -> list[GaussianThreshold]:
    """:func:`threshold` for several targets from one simulation and one bootstrap (``progress``: a
    status line per chunk of the simulation)."""
    started = time.process_time()
    budget = balanced(settings, budget)
    sim = simulate(settings, corr, budget, progress)
    found = [read_threshold(sim.events, sim.exposure, sim.grid, float(t), budget.streams, sim.weights)
             for t in targets]
    rng = np.random.default_rng([SEED, 2])
    boot: list[list[float]] = [[] for _ in targets]
    w = sim.weights[:, None]
    rates = w * nominal_rates(sim.events, sim.exposure, budget.streams)
    events, events_sq = w * sim.events, w ** 2 * sim.events
    nominals = rates.shape[0]
    for _ in range(BOOTSTRAP):
        count = np.bincount(rng.integers(0, nominals, nominals), minlength=nominals).astype(float)
        curve = (count @ rates / nominals, _effective(count @ events, count @ events_sq))   # a resample
        for k, target in enumerate(targets):
            try:
                boot[k].append(read_from_curve(*curve, sim.grid, float(target))[0])
            except ValueError:
                continue
    cpu = sim.cpu_s + time.process_time() - started
    return [GaussianThreshold(h, float(np.std(b, ddof=1)) if len(b) > 1 else math.inf, float(t), method, alarmed,
                              budget.nominals * budget.streams, budget.steps, cpu)
            for (h, method, alarmed), b, t in zip(found, boot, targets)]


@dataclass(frozen=True)
class Simulation:
    """First passages per nominal and grid threshold (G, H), their exposure [cycles], the grid [nats],
    the CPU time the simulation took [s] and each nominal's importance weight (G,)."""

    events: NDArray[np.float32]
    exposure: NDArray[np.float32]
    grid: NDArray[np.float64]
    cpu_s: float
    weights: NDArray[np.float64]


@functools.lru_cache(maxsize=32)
def simulate(settings: GaussianSettings, corr: Correlation, budget: GaussianBudget,
             progress: bool = False) -> Simulation:
    """The simulation of steps 1–3 of the module docstring (chunks of :data:`CHUNK` detectors; time in
    segments of :data:`SEGMENT` cycles, so memory stays O(CHUNK·(SEGMENT + grid)))."""
    started = time.process_time()
    r = np.asarray(corr, dtype=float)
    if settings.transform != "none" and r.shape[0] > 1:
        raise ValueError("a learned transform is simulated for scalar detectors only")
    if settings.spread_mean and len(settings.spread_mean) != r.shape[0]:
        raise ValueError(f"a spread law needs one spread per axis ({r.shape[0]}), got {settings.spread_mean!r}")
    if settings.learned_axes and budget.nominals % proposal_sets(settings, budget.drift_tilts):
        raise ValueError(f"the nominals ({budget.nominals}) must be a multiple of "
                         f"{proposal_sets(settings, budget.drift_tilts)} (every combination of proposals drawn "
                         "equally often); see balanced()")
    r = independent_learned_axes(r, settings.learned_axes)
    lower_chol = np.asarray(np.linalg.cholesky(r), dtype=float)
    rng = np.random.default_rng(SEED)
    grid = np.arange(H_STEP, H_MAX, H_STEP)
    per_chunk = max(1, CHUNK // budget.streams)
    shifts, drift_weights = stream_shifts(settings, budget.nominals, r.shape[0], budget.drift_tilts)
    events, exposure, weights = [], [], []
    for first in range(0, budget.nominals, per_chunk):
        g = min(per_chunk, budget.nominals - first)
        noise = StreamNoise(lower_chol, settings.wander, rng, settings.skew)
        scale = None
        if settings.in_learned_units:       # the measured law holds the learning error: the fit is exact
            index = np.arange(first, first + g)
            means, covs = np.zeros((g, 1)), np.ones((g, 1, 1))
            spread, weight = spread_draws(settings.spread_mean[0], settings.spread_sd[0], index)
            scale = np.repeat(spread, budget.streams)[:, None]
            learned = None
        elif settings.learned_axes:         # a vector with axes in learned units
            means, covs, weight, spread = partly_learned_fits(settings, np.arange(first, first + g), r, rng,
                                                              budget.drift_tilts)
            scale = np.repeat(spread, budget.streams, axis=0)
            learned = None
        elif not settings.wander:           # independent learning values: the fit's exact law
            index = np.arange(first, first + g)
            means, covs, weight = scalar_fits(settings.n0, index, rng) if r.shape[0] == 1 else \
                vector_fits(settings.n0, index, lower_chol, rng)
            learned = None if settings.transform == "none" else \
                LearnedTransforms.fit(rng.standard_normal((g, settings.n0)), means[:, 0], np.sqrt(covs[:, 0, 0]))
        else:
            samples = noise.sequence(g, settings.n0)
            means, covs = fit_nominals(samples)
            weight = np.ones(g)
            learned = None if settings.transform == "none" else LearnedTransforms.fit(samples[:, :, 0])
        if learned is not None:             # the detector's Gaussian is the transformed values'
            means, covs = learned.z_mean[:, None], learned.z_var[:, None, None]
        glr = fleet_detectors(settings, means, covs, budget.streams)
        weights.append(weight * drift_weights[first:first + g])
        shift = np.repeat(shifts[first:first + g], budget.streams, axis=0)
        observe = None if learned is None else learned.repeat(budget.streams).apply
        passage = first_passages(glr, shift, noise, budget.steps, grid, observe, scale)
        alarmed = passage < budget.steps
        shape = (g, budget.streams, grid.size)
        events.append(alarmed.reshape(shape).sum(axis=1))
        exposure.append(np.where(alarmed, passage + 1, budget.steps).reshape(shape).sum(axis=1))
        if progress:
            log.info("calibration simulation: %d/%d nominals", first + g, budget.nominals)
    ev, ex = np.concatenate(events).astype(np.float32), np.concatenate(exposure).astype(np.float32)   # exact
    used = int(np.flatnonzero(ev.sum(axis=0) > 0)[-1]) + 2 if ev.any() else 1
    return Simulation(ev[:, :used], ex[:, :used], grid[:used], time.process_time() - started,
                      np.concatenate(weights))


def balanced(settings: GaussianSettings, budget: GaussianBudget) -> GaussianBudget:
    """``budget`` with its nominals rounded up to whole :func:`proposal_sets` where ``settings`` have learned axes
    (their spread's weights are unbiased only so; other settings' budgets are checked by :class:`GaussianBudget`)."""
    if not settings.learned_axes:
        return budget
    sets = proposal_sets(settings, budget.drift_tilts)
    return replace(budget, nominals=-(-budget.nominals // sets) * sets)


def nominal_rates(events: NDArray[np.floating], exposure: NDArray[np.floating], streams: int) -> NDArray[np.float64]:
    """Per nominal and grid threshold (G, H): its false-alarm rate per cycle, e/X, or (e − 1)/X where
    none of its ``streams`` detectors was censored (then X is a sum of e exponential times and e/X
    overstates the rate)."""
    ev, ex = np.asarray(events, dtype=float), np.asarray(exposure, dtype=float)
    return np.where(ev < streams, ev, np.maximum(ev - 1.0, 0.0)) / ex


def _effective(weighted: NDArray[np.float64], weighted_sq: NDArray[np.float64]) -> NDArray[np.float64]:
    """Kish's effective count of weighted alarms, (Σ w·e)² / Σ w²·e (Σ e when every w = 1)."""
    return np.divide(weighted ** 2, weighted_sq, out=np.zeros_like(weighted), where=weighted_sq > 0)


def fleet_curve(events: NDArray[np.floating], exposure: NDArray[np.floating], streams: int,
                weights: NDArray[np.floating] | None = None) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Per grid threshold: the weighted mean over nominals of their rates (:func:`nominal_rates`) and the
    effective count of the detectors that alarmed (:func:`_effective`; their number without ``weights``)."""
    ev = np.asarray(events, dtype=float)
    w = np.ones((ev.shape[0], 1)) if weights is None else np.asarray(weights, dtype=float)[:, None]
    rate = (w * nominal_rates(ev, exposure, streams)).mean(axis=0)
    return rate, _effective((w * ev).sum(axis=0), (w ** 2 * ev).sum(axis=0))


def read_threshold(events: NDArray[np.floating], exposure: NDArray[np.floating], grid: NDArray[np.float64],
                   arl0: float, streams: int, weights: NDArray[np.floating] | None = None) -> tuple[float, str, int]:
    """h for ``arl0`` from per-nominal first passages ``events`` and ``exposure`` (G, H) on ``grid`` of
    ``streams`` detectors per nominal, weighted by ``weights`` (G,); ``ValueError`` when the simulation
    cannot tell (module docstring)."""
    return read_from_curve(*fleet_curve(events, exposure, streams, weights), grid, arl0)


def read_from_curve(rate: NDArray[np.float64], total: NDArray[np.float64], grid: NDArray[np.float64],
                    arl0: float) -> tuple[float, str, int]:
    """h for ``arl0`` from the fleet's rate and the (effective) alarmed detectors per grid threshold
    (:func:`fleet_curve`)."""
    reliable = np.flatnonzero((total >= MIN_EVENTS_DIRECT) & (rate > 0))
    if not reliable.size:
        raise ValueError("too few simulated alarms to calibrate; give a larger calibration budget")
    h, log_arl, counts = grid[reliable], -np.log(rate[reliable]), total[reliable]
    target = math.log(arl0)
    if log_arl[-1] >= target:
        k = int(np.argmax(log_arl >= target))
        if k == 0:
            return float(h[0]), "simulated", int(counts[0])
        return float(np.interp(target, log_arl[k - 1:k + 1], h[k - 1:k + 1])), "simulated", int(counts[k])
    tail = h >= h[-1] - 1.0 - 0.5 * H_STEP                        # the last nat of the reliable thresholds
    if tail.sum() < 3:
        raise ValueError("too few reliable simulated thresholds to extrapolate along")
    slope, intercept = np.polyfit(h[tail], log_arl[tail], 1)
    if not slope > 0:
        raise ValueError("the simulated run lengths do not grow with the threshold; cannot extrapolate")
    return max(float((target - intercept) / slope), float(h[-1])), "extrapolated", int(counts[-1])
