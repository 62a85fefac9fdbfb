"""Thresholds for a stated mean run length to false alarm (ARL0), calibrated by simulation.

The user states how many cycles a detector should run, on average, before a false alarm (ARL0). At
the end of its learning phase a detector calibrates its own threshold h for that, from its own
learned nominal density p̂0, by simulating the exact sequential statistic it runs (window, maximum
over candidate change times, SA-EM, recursive or exact numerator; :mod:`edge_monitor.stats.glr_batch`)
including the error of learning the nominal from N0 values — a parametric bootstrap:

1. draw B/4 nominal sets of N0 values from p̂0 and fit each with the detector's density family;
2. run 4 detectors per refitted density (``STREAMS_PER_NOMINAL``, B in all) on independent streams
   drawn from p̂0, ``steps`` cycles long, each nominal's streams shifted by a constant that says what
   healthy data the target is for (:func:`stream_shifts`: none, the drift allowance, or a fleet of
   healthy drifts), recording each detector's statistic;
3. for every candidate h, the first-passage times T_b(h) of each nominal's 4 detectors give its
   false-alarm rate, and E[T](h) is 1 / the mean of those rates over the nominals: the fleet's run
   length (:func:`fleet_run_lengths`; pooling all first passages, Σ min(T_b, L) / #{T_b ≤ L}, would
   give about the harmonic mean of the rates, smaller than what a fleet sees);
4. h is where E[T](h) = ARL0: interpolated where the simulation reaches ARL0 with little censoring,
   else extrapolated along the straight line log E[T] = a + c·h fitted to the upper part of the
   reliable range (``method="extrapolated"``).

With ``simulate_from="values"`` the nominal sets and the streams are drawn from the learned values
themselves instead of p̂0 (:class:`SmoothedBootstrap`): the detector still assumes p̂0, but its
threshold is set for data shaped as its nominal values are (a Gaussian nominal of values with light
tails or a skew between axes states a heavier tail than the data have, and would alarm less often
than stated).

The run lengths of detectors learned from different nominal sets differ a lot (one learned with a
too narrow density alarms early), so E[T] averages over learning as the operator's fleet does;
docs/DETECTION.md shows the measured ARL0 of the agent's detectors against the targets. Cost: about
B·steps·W·K mixture evaluations; deterministic for a given seed.
"""

from __future__ import annotations

import logging
import math
import time
from dataclasses import asdict, dataclass
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.stats import norm

from edge_monitor.stats import threshold_table
from edge_monitor.stats.densities import DensityError, GaussianMixture, as_observations, fit_density
from edge_monitor.stats.gaussian_calibration import GaussianBudget, GaussianSettings, correlation
from edge_monitor.stats.gaussian_calibration import threshold as gaussian_threshold
from edge_monitor.stats.glr_batch import (
    BatchWindowedGLR,
    GLRMode,
    MixtureBatch,
    clip_range,
    null_box,
    stack_bounds,
)
from edge_monitor.stats.smoothed_bootstrap import Sampler, SmoothedBootstrap

log = logging.getLogger(__name__)

#: Default mean run length to false alarm per detector [cycles] (at 300 cycles a day: ~1 per month).
DEFAULT_ARL0 = 10_000.0
#: Largest ARL0 a user may ask for [cycles]: beyond, the extrapolation is not trustworthy.
MAX_ARL0 = 1e7
#: Smallest ARL0 a detector may be calibrated for [cycles].
MIN_ARL0 = 10.0
#: A threshold is read off where at most this fraction of the simulated detectors never alarmed.
MAX_CENSORED = 0.10
#: … and at least this many alarmed.
MIN_EVENTS = 10
#: Threshold grid step [nats].
H_STEP = 0.05
#: Simulated detectors per learned nominal: their first passages estimate that nominal's false-alarm
#: rate, and the rates are averaged over the nominals (:func:`fleet_run_lengths`).
STREAMS_PER_NOMINAL = 4
#: Where the simulated streams of a calibration sit (:func:`stream_shifts`).
CALIBRATE_AT = ("healthy_drift", "boundary", "nominal")
#: Largest healthy drift a calibration accepts, mean or sd [standard deviations of the nominal values].
MAX_DRIFT = 5.0
#: Largest skew-normal shape |α| a warm-up law accepts (α = ±10: skewness ±0.96, nearly a half-normal's).
MAX_SKEW = 10.0
#: What the simulated nominal sets and streams are drawn from: the fitted density or the values.
SIMULATE_FROM = ("model", "values")
#: Seed of every simulation of a mixture density (the same learned values give the same threshold).
FIXED_SEED = 20261126
#: Detectors of a Gaussian calibration per ``calibration_draws``: its closed-form recursion is ≈ 8×
#: cheaper per detector than the mixture's, so its precision is bought with more detectors.
GAUSSIAN_DRAW_FACTOR = 8


class CalibrationError(ValueError):
    """The calibration could not produce a threshold (degenerate nominal data)."""


@dataclass(frozen=True)
class CalibrationBudget:
    """How much simulation a calibration may use: ``draws`` bootstrap detectors, each run for
    ``steps_per_arl0``·ARL0 cycles clipped to [``min_steps``, ``max_steps``]."""

    draws: int = 48
    min_steps: int = 600
    max_steps: int = 2000
    steps_per_arl0: float = 12.0

    def steps(self, arl0: float) -> int:
        return int(min(max(self.steps_per_arl0 * arl0, self.min_steps), self.max_steps))


@dataclass(frozen=True)
class Calibration:
    """A calibrated threshold h [nats] for the mean run length ``arl0`` [cycles], how it was found,
    and what it cost (``cpu_s``)."""

    threshold: float
    arl0: float
    method: str                   # "simulated" | "extrapolated"
    draws: int
    steps: int
    events: int                   # simulated detectors that alarmed within ``steps`` at the threshold
    slope: float | None           # fitted d log E[T] / dh [1/nat] when extrapolated
    cpu_s: float
    at: str = "boundary"          # where the simulated streams sat (:func:`stream_shifts`)
    h_se: float | None = None     # Monte Carlo standard error of the threshold [nats] (Gaussian path)

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)

    @classmethod
    def from_dict(cls, state: dict[str, Any]) -> "Calibration":
        return cls(threshold=float(state["threshold"]), arl0=float(state["arl0"]), method=str(state["method"]),
                   draws=int(state["draws"]), steps=int(state["steps"]), events=int(state["events"]),
                   slope=None if state.get("slope") is None else float(state["slope"]),
                   cpu_s=float(state.get("cpu_s", 0.0)), at=str(state.get("at", "boundary")),
                   h_se=None if state.get("h_se") is None else float(state["h_se"]))


def _calibrate_gaussian(values: NDArray[np.float64], window: int, arl0: float, gamma0: float, rho: float,
                        budget: CalibrationBudget, direction: str, allowance: float, clip_sigma: float,
                        at: str, drift_mean: tuple[float, ...] = (), drift_sd: tuple[float, ...] = (),
                        wander: tuple[float, ...] = (), transform: str = "none",
                        law: tuple[tuple[float, ...], ...] = ((), (), ())) -> Calibration:
    """A Gaussian nominal's threshold in standard units (:mod:`~edge_monitor.stats.gaussian_calibration`):
    tabulated for the shipped settings (:mod:`~edge_monitor.stats.threshold_table`), else simulated
    (cached) with ``GAUSSIAN_DRAW_FACTOR`` × ``budget.draws`` detectors of ``budget.steps(arl0)`` cycles; ``law``:
    a warm-up law in learned units, (spread mean, spread sd, skew) as :class:`GaussianSettings` takes them."""
    settings = GaussianSettings(len(values), int(window), float(gamma0), float(rho), direction, float(allowance),
                                float(clip_sigma), at, drift_mean, drift_sd, wander, transform, *law)
    try:
        corr = correlation(values)
    except (ValueError, np.linalg.LinAlgError) as exc:
        raise CalibrationError(f"Gaussian calibration failed: {exc}") from None
    found = threshold_table.lookup(settings, arl0, corr)
    if found is None:
        detectors = GAUSSIAN_DRAW_FACTOR * budget.draws
        gauss_budget = GaussianBudget(nominals=max(detectors // STREAMS_PER_NOMINAL, 8), streams=STREAMS_PER_NOMINAL,
                                      steps=budget.steps(arl0))
        if not gauss_budget.reaches(arl0):     # a deep target: the drift's tail importance-sampled
            gauss_budget = gauss_budget.tilted()
        try:
            found = gaussian_threshold(settings, corr, arl0, gauss_budget)
        except (ValueError, np.linalg.LinAlgError) as exc:
            raise CalibrationError(f"Gaussian calibration failed: {exc}") from None
    return Calibration(threshold=found.threshold, arl0=float(arl0), method=found.method, draws=found.detectors,
                       steps=found.steps, events=found.events, slope=None, cpu_s=found.cpu_s, at=at,
                       h_se=found.h_se)


def calibrate(nominal: ArrayLike, kind: str, window: int, arl0: float, gamma0: float = 0.6, rho: float = 1.0,
              mode: GLRMode = "recursive", budget: CalibrationBudget = CalibrationBudget(),
              seed: int | None = None, direction: str = "both", allowance: float = 0.0,
              clip_sigma: float = 0.0, at: str = "boundary", drift_mean: ArrayLike = (),
              drift_sd: ArrayLike = (), simulate_from: str = "model", wander: ArrayLike = (),
              transform: str = "none", spread_mean: ArrayLike = (), spread_sd: ArrayLike = (),
              skew: ArrayLike = ()) -> Calibration:
    """The threshold for mean run length ``arl0`` of a detector that learned ``nominal`` (N0 × d)
    with the ``kind`` density (see the module docstring); ``direction`` and ``allowance`` set the
    null hypothesis as the detector does (:func:`~edge_monitor.stats.glr_batch.null_box`) and
    ``clip_sigma`` its winsorisation (:func:`~edge_monitor.stats.glr_batch.clip_range`), each
    bootstrap detector from its own nominal set. ``at`` says where the simulated streams sit
    (:func:`stream_shifts`): ``"boundary"`` (the agent's default), ``"healthy_drift"`` or ``"nominal"``;
    ``drift_mean``/``drift_sd`` (one per dimension, in standard deviations of the nominal values)
    describe the healthy drift for ``"healthy_drift"``, ``wander`` (per dimension, a variance fraction)
    its slow serial wander (Gaussian nominals only, :mod:`~edge_monitor.stats.gaussian_calibration`);
    ``transform``: ``"yeo-johnson"`` when ``nominal`` holds the values of a scalar detector after a transform it
    learned from them, whose exponent's learning error the Gaussian path then simulates too. ``spread_mean``/
    ``spread_sd`` (a scalar Gaussian nominal at ``"healthy_drift"``): the healthy joint's law in the nominal's
    learned units, its drift and spread measured there with the learning error in them, which is then not
    drawn again (:class:`~edge_monitor.stats.gaussian_calibration.GaussianSettings`); ``skew``, with that law: the
    skew-normal shape of the values' iid part (their upper tail as measured).
    ``simulate_from``: ``"model"`` (p̂0) or ``"values"`` (:class:`SmoothedBootstrap` of ``nominal``), see
    the module docstring."""
    if at not in CALIBRATE_AT:
        raise ValueError(f"at = {at!r}; choose one of {CALIBRATE_AT}")
    if simulate_from not in SIMULATE_FROM:
        raise ValueError(f"simulate_from = {simulate_from!r}; choose one of {SIMULATE_FROM}")
    started = time.process_time()
    values = as_observations(nominal, name="nominal data")
    if kind == "gauss" and simulate_from == "model" and mode == "recursive":
        def per_axis(given: ArrayLike) -> tuple[float, ...]:      # only a healthy-drift calibration uses them
            return tuple(float(x) for x in np.ravel(given)) if at == "healthy_drift" else ()

        return _calibrate_gaussian(values, window, arl0, gamma0, rho, budget, direction, allowance, clip_sigma, at,
                                   per_axis(drift_mean), per_axis(drift_sd), per_axis(wander), transform,
                                   (per_axis(spread_mean), per_axis(spread_sd), per_axis(skew)))
    if len(np.ravel(spread_mean)) or len(np.ravel(skew)):
        raise ValueError("a spread law is simulated for Gaussian nominals only (kind 'gauss', model, recursive)")
    seed = FIXED_SEED if seed is None else seed
    rng = np.random.default_rng(seed)
    model = fit_density(values, kind)
    truth: Sampler = model if simulate_from == "model" else SmoothedBootstrap(values)
    nominals = -(-budget.draws // STREAMS_PER_NOMINAL)
    mixtures, samples = _bootstrap_densities(truth, len(values), kind, nominals, rng)
    shifts = stream_shifts(values.std(axis=0, ddof=1), nominals, at, allowance, drift_mean, drift_sd,
                           np.random.default_rng([seed, 1]))      # its own stream: the draws stay the same
    each = np.repeat(np.arange(nominals), STREAMS_PER_NOMINAL)    # detector → its learned nominal
    boxes = stack_bounds([null_box(samples[i], direction, allowance) for i in each])
    clips = stack_bounds([clip_range(samples[i], clip_sigma) for i in each])
    steps = budget.steps(arl0)
    statistics = _simulate(truth, [mixtures[i] for i in each], boxes, clips, window, gamma0, rho, mode, steps,
                           rng, shifts[each])
    drifting = at == "healthy_drift" and bool(np.any(np.asarray(drift_sd, dtype=float) > 0))
    threshold, method, events, slope = _threshold_for(statistics, arl0, nominals, drifting)
    return Calibration(threshold=threshold, arl0=float(arl0), method=method, draws=len(each), steps=steps,
                       events=events, slope=slope, cpu_s=time.process_time() - started, at=at)


def stream_shifts(spread: NDArray[np.float64], draws: int, at: str, allowance: float = 0.0,
                  drift_mean: ArrayLike = (), drift_sd: ArrayLike = (),
                  rng: np.random.Generator | None = None) -> NDArray[np.float64]:
    """The constant shift (draws × d) added to each simulated stream, in the units of the values;
    ``spread`` (d,) is the std of the nominal values.

    * ``"nominal"``: none — the learned nominal itself (a stationary healthy joint);
    * ``"boundary"``: ``allowance``·spread for every draw — the least favourable nominal, the largest
      shift H0 allows on the watched side; the target then holds for the worst tolerated drift and a
      healthy fleet runs longer;
    * ``"healthy_drift"``: draw b is shifted by (``drift_mean`` + ``drift_sd``·z_b)·spread with z_b
      the stratified normal quantiles Φ⁻¹((b + ½)/B) in random order, one z_b for all dimensions
      (the two KL distances of a joint drift together; the wear score does not, so this overstates
      the joint vector's drift). The simulated detectors are then a healthy fleet whose joints each
      sit at their own drift after warm-up, and the threshold holds that fleet's false-alarm rate
      (:func:`fleet_run_lengths`).
    """
    d = spread.size
    if at == "nominal":
        return np.zeros((draws, d))
    if at == "boundary":
        return np.tile(float(allowance) * spread, (draws, 1))
    mean = np.broadcast_to(np.asarray(drift_mean, dtype=float), (d,))
    sd = np.broadcast_to(np.asarray(drift_sd, dtype=float), (d,))
    z = norm.ppf((np.arange(draws) + 0.5) / draws)
    z = (rng or np.random.default_rng(0)).permutation(z)
    return (mean[None, :] + sd[None, :] * z[:, None]) * spread[None, :]


def _bootstrap_densities(truth: Sampler, n0: int, kind: str, draws: int, rng: np.random.Generator
                         ) -> tuple[list[GaussianMixture], list[NDArray[np.float64]]]:
    """B densities refitted on nominal sets drawn from ``truth``, and those sets."""
    mixtures: list[GaussianMixture] = []
    samples: list[NDArray[np.float64]] = []
    attempts = 0
    while len(mixtures) < draws:
        attempts += 1
        if attempts > 4 * draws:
            raise CalibrationError(f"only {len(mixtures)} of {draws} bootstrap densities could be fitted")
        sample = truth.sample(n0, rng)
        try:
            mixtures.append(fit_density(sample, kind))
        except DensityError:
            continue
        samples.append(sample)
    return mixtures, samples


def _simulate(truth: Sampler, mixtures: list[GaussianMixture],
              boxes: tuple[NDArray[np.float64], NDArray[np.float64]],
              clips: tuple[NDArray[np.float64], NDArray[np.float64]], window: int, gamma0: float, rho: float,
              mode: GLRMode, steps: int, rng: np.random.Generator, shifts: NDArray[np.float64]) -> NDArray[np.float64]:
    """Statistics (B, steps) of B detectors on streams drawn from ``truth``, stream b shifted by ``shifts[b]``."""
    glr = BatchWindowedGLR(MixtureBatch(mixtures), window, gamma0, rho, mode, null_box=boxes, clip=clips)
    stream = truth.sample(len(mixtures) * steps, rng).reshape(len(mixtures), steps, truth.dim) + shifts[:, None, :]
    out = np.empty((len(mixtures), steps))
    for t in range(steps):
        out[:, t] = glr.update(stream[:, t])
    return out


def _passages(statistics: NDArray[np.float64], thresholds: NDArray[np.float64]
              ) -> tuple[NDArray[np.float64], NDArray[np.int64]]:
    """Per threshold: the cycles the detectors ran until their first passage or the end (exposure),
    and how many passed. ``statistics`` (B, L) of B detectors over L cycles."""
    steps = statistics.shape[1]
    running = np.maximum.accumulate(statistics, axis=1)          # non-decreasing: first passage by bisection
    below = np.stack([np.searchsorted(row, thresholds, side="left") for row in running])   # (B, H)
    alarmed = below < steps
    return np.where(alarmed, below + 1, steps).sum(axis=0).astype(float), alarmed.sum(axis=0)


def mean_run_lengths(statistics: NDArray[np.float64], thresholds: NDArray[np.float64]
                     ) -> tuple[NDArray[np.float64], NDArray[np.int64], NDArray[np.float64]]:
    """For each threshold: the censored exponential estimate of E[T], the number of detectors that
    alarmed, and the censored fraction. ``statistics`` (B, L) of B detectors over L cycles."""
    exposure, events = _passages(statistics, thresholds)
    with np.errstate(divide="ignore"):
        mean = np.where(events > 0, exposure / np.maximum(events, 1), np.inf)
    return mean, events, 1.0 - events / statistics.shape[0]


def fleet_run_lengths(statistics: NDArray[np.float64], thresholds: NDArray[np.float64], groups: int
                      ) -> tuple[NDArray[np.float64], NDArray[np.int64]]:
    """The mean run length a fleet sees whose detectors each learned their own nominal: ``statistics``
    (B, L) cut into ``groups`` consecutive groups of detectors that share one learned nominal (and one
    drift). A group's false-alarm rate is (e − 1)/X from its e first passages in X cycles of exposure
    (the censored exponential rate e/X with the small-sample correction that makes it unbiased for
    exponential passages: e/X overstates the rate of m passages by m/(m − 1)); the fleet's rate is the
    mean of the groups' rates — what a fleet that renews each detector after a false alarm sees.
    Pooling all first passages instead gives about the harmonic mean of the rates, which understates
    the fleet's rate whenever the learned nominals differ. Returns 1 / that rate and the number of
    detectors that alarmed, per threshold."""
    rates = []
    for group in np.array_split(statistics, groups):
        exposure, events = _passages(group, thresholds)
        rates.append(np.maximum(events - 1, 0) / exposure)
    rate = np.mean(rates, axis=0)
    _, events = _passages(statistics, thresholds)
    return np.divide(1.0, rate, out=np.full_like(rate, np.inf), where=rate > 0), events


def _threshold_for(statistics: NDArray[np.float64], arl0: float, groups: int = 1, drifting: bool = False
                   ) -> tuple[float, str, int, float | None]:
    """The threshold for ``arl0`` from the simulated statistics (B, L) of ``groups`` groups of detectors
    sharing a learned nominal (:func:`fleet_run_lengths`; 1: pooled first passages). ``drifting``:
    each group sits at its own healthy drift, so slowly alarming groups are censored by nature, not by
    budget, and censoring does not limit the reliable range."""
    top = float(np.max(statistics))
    if not math.isfinite(top) or top <= 0:
        raise CalibrationError("the simulated statistics are degenerate (no spread in the nominal data?)")
    grid = np.arange(H_STEP, top + H_STEP, H_STEP)
    if groups > 1:
        mean, events = fleet_run_lengths(statistics, grid, groups)
    else:
        mean, events, _ = mean_run_lengths(statistics, grid)
    reliable = (events >= MIN_EVENTS) & (drifting or (1.0 - events / len(statistics) <= MAX_CENSORED))
    if not reliable.any():
        raise CalibrationError("too few simulated alarms to calibrate; give a larger calibration budget")
    last = int(np.flatnonzero(reliable)[-1])
    log_mean = np.log(mean[: last + 1])
    if mean[last] >= arl0:                        # interpolate inside the simulated range
        k = int(np.argmax(log_mean >= math.log(arl0)))     # the first grid point reaching ARL0
        if k == 0:                                # already at the smallest threshold of the grid
            return float(grid[0]), "simulated", int(events[0]), None
        h = float(np.interp(math.log(arl0), log_mean[k - 1:k + 1], grid[k - 1:k + 1]))
        return h, "simulated", int(events[k]), None
    # extrapolate along the upper half of the reliable range (log E[T] is close to linear in h there)
    if last == 0:
        raise CalibrationError("one reliable simulated threshold only, no line to extrapolate along; "
                               "give a larger calibration budget")
    lo = int(np.flatnonzero(mean >= math.sqrt(max(mean[0], 1.0) * mean[last]))[0])
    lo = min(lo, max(last - 10, 0))
    slope, intercept = np.polyfit(grid[lo:last + 1], log_mean[lo:last + 1], 1)
    if not slope > 0:
        raise CalibrationError("the simulated run lengths do not grow with the threshold; cannot extrapolate")
    h = float((math.log(arl0) - intercept) / slope)
    return max(h, float(grid[last])), "extrapolated", int(events[last]), float(slope)


@dataclass(frozen=True)
class CalibrationJob:
    """Everything a calibration needs (picklable: it may run in another process)."""

    nominal: tuple[tuple[float, ...], ...]
    kind: str
    window: int
    arl0: float
    gamma0: float
    rho: float
    mode: str
    budget: CalibrationBudget
    direction: str = "both"
    allowance: float = 0.0
    clip_sigma: float = 0.0
    at: str = "boundary"
    drift_mean: tuple[float, ...] = ()
    drift_sd: tuple[float, ...] = ()
    simulate_from: str = "model"
    wander: tuple[float, ...] = ()
    transform: str = "none"
    spread_mean: tuple[float, ...] = ()
    spread_sd: tuple[float, ...] = ()
    skew: tuple[float, ...] = ()

    def run(self) -> Calibration:
        return calibrate(np.asarray(self.nominal), self.kind, self.window, self.arl0, self.gamma0, self.rho,
                         "exact" if self.mode == "exact" else "recursive", self.budget,
                         direction=self.direction, allowance=self.allowance, clip_sigma=self.clip_sigma,
                         at=self.at, drift_mean=self.drift_mean, drift_sd=self.drift_sd,
                         simulate_from=self.simulate_from, wander=self.wander, transform=self.transform,
                         spread_mean=self.spread_mean, spread_sd=self.spread_sd, skew=self.skew)

    def to_dict(self) -> dict[str, Any]:
        return {**asdict(self), "nominal": [list(v) for v in self.nominal], "budget": asdict(self.budget),
                "drift_mean": list(self.drift_mean), "drift_sd": list(self.drift_sd), "wander": list(self.wander),
                "spread_mean": list(self.spread_mean), "spread_sd": list(self.spread_sd), "skew": list(self.skew)}

    @classmethod
    def from_dict(cls, state: dict[str, Any]) -> "CalibrationJob":
        return cls(nominal=tuple(tuple(float(x) for x in v) for v in state["nominal"]), kind=str(state["kind"]),
                   window=int(state["window"]), arl0=float(state["arl0"]), gamma0=float(state["gamma0"]),
                   rho=float(state["rho"]), mode=str(state["mode"]), budget=CalibrationBudget(**state["budget"]),
                   direction=str(state.get("direction", "both")), allowance=float(state.get("allowance", 0.0)),
                   clip_sigma=float(state.get("clip_sigma", 0.0)), at=str(state.get("at", "boundary")),
                   drift_mean=tuple(float(x) for x in state.get("drift_mean", ())),
                   drift_sd=tuple(float(x) for x in state.get("drift_sd", ())),
                   simulate_from=str(state.get("simulate_from", "model")),
                   wander=tuple(float(x) for x in state.get("wander", ())),
                   transform=str(state.get("transform", "none")),
                   spread_mean=tuple(float(x) for x in state.get("spread_mean", ())),
                   spread_sd=tuple(float(x) for x in state.get("spread_sd", ())),
                   skew=tuple(float(x) for x in state.get("skew", ())))
