"""Settings of one sequential detector (:mod:`edge_monitor.stats.sequential_detector`), validated once,
here, with the defaults the agent ships (docs/ALGORITHMS.md §6, docs/DETECTION.md)."""

from __future__ import annotations

from dataclasses import asdict, dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from edge_monitor.errors import ConfigError, require
from edge_monitor.stats.bias_em import BiasEMError, check_gain
from edge_monitor.stats.calibration import (
    CALIBRATE_AT,
    DEFAULT_ARL0,
    MAX_ARL0,
    MAX_DRIFT,
    MAX_SKEW,
    MIN_ARL0,
    MIN_EVENTS,
    SIMULATE_FROM,
    CalibrationBudget,
)
from edge_monitor.stats.densities import DENSITY_KINDS, min_points, with_sd_prior
from edge_monitor.stats.gaussian_calibration import GaussianSettings
from edge_monitor.stats.glr import MAX_WINDOW, GLRError, check_pf
from edge_monitor.stats.glr_batch import DIRECTIONS
from edge_monitor.stats.normalising_transform import TRANSFORMS
from protocol.numbers import is_finite_number

#: Candidate change times kept by the agent's detectors [cycles].
DEFAULT_WINDOW = 100
#: Learning phase length [cycles] (docs/ALGORITHMS.md §6: 50 … 70).
DEFAULT_NOMINAL = 60
#: Learning phase of the steady nominal [cycles]: 4 × the first, a margin against the learning error
#: (a nominal learned too narrow alarms early; docs/DETECTION.md, "Two stages").
DEFAULT_STEADY_NOMINAL = 240
#: Settings of where a calibration simulates the detector (the point, the drift after learning, the wander): not
#: what the detector learned, so a saved nominal stays valid when they change and its threshold is re-derived
#: (``SequentialDetector.from_state``), like a changed target.
CALIBRATION_KEYS = ("calibrate_at", "drift_mean", "drift_sd", "spread_mean", "spread_sd", "warm_up_wander",
                    "warm_up_skew", "steady_at", "steady_drift_mean", "steady_drift_sd", "steady_wander")
#: The steady settings a detector learns with (the rest of :data:`STEADY_DEFAULTS`, after the calibration point).
STEADY_LEARNED = ("steady_nominal", "steady_density", "steady_transform", "steady_simulate_from")
#: (steady_at, steady_nominal, steady_density, steady_transform, steady_simulate_from) of the agent: left out of the
#: fingerprint, so that states saved before the steady stage existed still match (a saved steady
#: nominal without a transform is watched untransformed, as it was learned).
STEADY_DEFAULTS = ("healthy_drift", DEFAULT_STEADY_NOMINAL, "gauss", "yeo-johnson", "model")
#: The warm-up sd prior's settings: left out of a fingerprint where empty.
SD_PRIOR_KEYS = ("sd_prior_count", "sd_prior_sd")
#: Longest learning phase [cycles]: the nominal values are kept until the density is fitted.
MAX_NOMINAL = 10_000
#: GLR numerator mode. "recursive" is the O(W·K) variant (≈ 0.2 ms per update at W = 100);
#: "exact" is O(W²·K). The calibration simulates whichever the detector runs.
DEFAULT_MODE = "recursive"


class DetectorConfigError(ConfigError):
    """Invalid detector setting (names the parameter and the valid range)."""


@dataclass(frozen=True)
class DetectorConfig:
    """Settings of one sequential detector, validated once, here.

    ``arl0``: mean run length to false alarm [cycles] the threshold is calibrated for; ``pf``: instead,
    the per-test false-alarm probability of the asymptotic threshold (expert option; then ``arl0`` is
    not used). ``calibration_draws``/``calibration_steps``: simulation budget of the calibration;
    ``calibrate_at``, ``drift_mean``/``drift_sd`` [σ of the nominal values, one per dimension]: which
    healthy data the target is for (:func:`~edge_monitor.stats.calibration.stream_shifts`);
    ``steady_at``, ``steady_drift_mean``/``steady_drift_sd`` [σ, per dimension; empty: none],
    ``steady_wander`` [variance fraction of a slow AR(1) wander, per dimension; empty: none],
    ``steady_nominal`` [cycles]: how the nominal learned once the temperature has settled
    is calibrated, and from how many values (more than ``n_nominal``: a margin against its learning error);
    ``steady_density``: its density family, fitted after ``steady_transform`` ("yeo-johnson": per-axis
    :class:`~edge_monitor.stats.normalising_transform.YeoJohnson` learned from the same values, on the
    axes ``transform_axes`` flags (empty: all), or "none") (docs/DETECTION.md, "Two stages").
    """

    dim: int = 1
    n_nominal: int = DEFAULT_NOMINAL
    density: str = "gauss"
    window: int = DEFAULT_WINDOW
    gamma0: float = 0.6
    rho: float = 1.0
    mode: str = DEFAULT_MODE
    arl0: float = DEFAULT_ARL0
    pf: float | None = None
    direction: str = "both"
    allowance: float = 0.0
    clip_sigma: float = 0.0
    calibration_draws: int = CalibrationBudget().draws
    calibration_steps: int = CalibrationBudget().max_steps
    calibrate_at: str = "boundary"
    drift_mean: tuple[float, ...] = ()
    drift_sd: tuple[float, ...] = ()
    spread_mean: tuple[float, ...] = ()     # warm-up: the healthy drift (above) and this spread law are in the
    spread_sd: tuple[float, ...] = ()       # nominal's learned units (docs/DETECTION.md; a vector: per axis, 0 none)
    warm_up_wander: tuple[float, ...] = ()  # wandering with this variance fraction (a spread law only)
    warm_up_skew: tuple[float, ...] = ()    # skew-normal shape of their iid part, its upper tail (a spread law only)
    steady_at: str = "healthy_drift"
    steady_drift_mean: tuple[float, ...] = ()
    steady_drift_sd: tuple[float, ...] = ()
    steady_wander: tuple[float, ...] = ()
    steady_nominal: int = DEFAULT_STEADY_NOMINAL
    steady_density: str = "gauss"
    steady_transform: str = "yeo-johnson"
    transform_axes: tuple[bool, ...] = ()
    steady_simulate_from: str = "model"
    sd_prior_count: tuple[float, ...] = ()  # warm-up: per axis k pseudo-values of sd sd_prior_sd that the learned
    sd_prior_sd: tuple[float, ...] = ()     # sd is shrunk towards (densities.with_sd_prior; 0 none; empty: none)

    def __post_init__(self) -> None:
        try:
            require(isinstance(self.dim, int) and 1 <= self.dim <= 16, "dim", f"must be 1 … 16, got {self.dim!r}")
            require(self.density in DENSITY_KINDS, "density", f"{self.density!r}; choose one of {DENSITY_KINDS}")
            need = min_points(self.density, self.dim)
            require(isinstance(self.n_nominal, int) and need <= self.n_nominal <= MAX_NOMINAL, "n_nominal",
                    f"{self.n_nominal!r} cycles: the {self.density!r} density in dimension {self.dim} needs "
                    f"{need} … {MAX_NOMINAL} (default {DEFAULT_NOMINAL})")
            require(self.steady_transform in TRANSFORMS, "steady_transform",
                    f"{self.steady_transform!r}; choose one of {TRANSFORMS}")
            require(self.steady_simulate_from in SIMULATE_FROM, "steady_simulate_from",
                    f"{self.steady_simulate_from!r}; choose one of {SIMULATE_FROM}")
            require(len(self.transform_axes) in (0, self.dim) and all(isinstance(a, bool) for a in self.transform_axes),
                    "transform_axes", f"needs {self.dim} true/false flag(s) or none, got {self.transform_axes!r}")
            require(self.steady_density in DENSITY_KINDS, "steady_density",
                    f"{self.steady_density!r}; choose one of {DENSITY_KINDS}")
            need = min_points(self.steady_density, self.dim)
            require(isinstance(self.steady_nominal, int) and need <= self.steady_nominal <= MAX_NOMINAL,
                    "steady_nominal", f"{self.steady_nominal!r} cycles: the {self.steady_density!r} density in "
                    f"dimension {self.dim} needs {need} … {MAX_NOMINAL} (default {DEFAULT_STEADY_NOMINAL})")
            require(isinstance(self.window, int) and 1 <= self.window <= MAX_WINDOW, "window",
                    f"must be 1 … {MAX_WINDOW} cycles, got {self.window!r} (default {DEFAULT_WINDOW})")
            require(self.mode in ("exact", "recursive"), "mode", f"must be 'exact' or 'recursive', got {self.mode!r}")
            require(isinstance(self.arl0, (int, float)) and MIN_ARL0 <= self.arl0 <= MAX_ARL0, "arl0",
                    f"mean run length to false alarm must be {MIN_ARL0:g} … {MAX_ARL0:g} cycles, got {self.arl0!r}")
            require(self.direction in DIRECTIONS, "direction", f"{self.direction!r}; choose one of {DIRECTIONS}")
            require(isinstance(self.allowance, (int, float)) and 0 <= self.allowance <= 5, "allowance",
                    f"must be 0 … 5 standard deviations of the nominal values, got {self.allowance!r}")
            require(isinstance(self.clip_sigma, (int, float)) and (self.clip_sigma == 0 or 1 <= self.clip_sigma <= 20),
                    "clip_sigma", f"must be 0 (off) or 1 … 20 standard deviations, got {self.clip_sigma!r}")
            require(isinstance(self.calibration_draws, int) and MIN_EVENTS <= self.calibration_draws <= 4096,
                    "calibration_draws", f"must be {MIN_EVENTS} … 4096 (a threshold needs {MIN_EVENTS} simulated "
                    f"alarms), got {self.calibration_draws!r}")
            require(isinstance(self.calibration_steps, int) and 200 <= self.calibration_steps <= 1_000_000,
                    "calibration_steps", f"must be 200 … 1000000, got {self.calibration_steps!r}")
            for name in ("calibrate_at", "steady_at"):
                require(getattr(self, name) in CALIBRATE_AT, name,
                        f"{getattr(self, name)!r}; choose one of {CALIBRATE_AT}")
            bounds = []
            if self.calibrate_at == "healthy_drift":
                bounds += [("drift_mean", self.drift_mean, -MAX_DRIFT), ("drift_sd", self.drift_sd, 0.0)]
            if self.steady_at == "healthy_drift":
                bounds += [("steady_drift_mean", self.steady_drift_mean or (0.0,) * self.dim, -MAX_DRIFT),
                           ("steady_drift_sd", self.steady_drift_sd or (0.0,) * self.dim, 0.0)]
            require(self.steady_wander == () or (len(self.steady_wander) == self.dim and all(
                isinstance(v, (int, float)) and 0.0 <= v < 1.0 for v in self.steady_wander)), "steady_wander",
                f"needs none or {self.dim} variance fraction(s) in 0 … <1, got {self.steady_wander!r}")
            for name in ("spread_mean", "spread_sd", "warm_up_skew", "warm_up_wander"):
                require(isinstance(getattr(self, name), tuple), name, f"a tuple, got {getattr(self, name)!r}")
            law = (*self.spread_mean, *self.spread_sd, *self.warm_up_skew)
            require(self.spread_mean == self.spread_sd == () or (
                self.calibrate_at == "healthy_drift" and len(self.spread_mean) == len(self.spread_sd) == self.dim
                and all(is_finite_number(v) for v in law)
                and all(0.05 <= m <= 5 or (m == 0 and self.dim > 1 and sd == 0)
                        for m, sd in zip(self.spread_mean, self.spread_sd))
                and any(self.spread_mean) and all(0 <= sd <= MAX_DRIFT for sd in self.spread_sd)), "spread_mean",
                f"a spread law is one per axis (mean 0.05 … 5, a vector's axis 0 with sd 0 where it keeps its learning "
                f"error; sd 0 … {MAX_DRIFT:g}) for a detector calibrated at the healthy drift, got "
                f"{self.spread_mean!r}, {self.spread_sd!r}")
            require(self.warm_up_wander == () or (self.dim == len(self.spread_mean) == len(self.warm_up_wander) == 1
                                                  and 0.0 <= self.warm_up_wander[0] < 1.0), "warm_up_wander",
                    f"one variance fraction in 0 … <1, with a scalar's spread law only, got {self.warm_up_wander!r}")
            require(self.warm_up_skew == () or (len(self.spread_mean) == len(self.warm_up_skew) and all(
                abs(a) <= MAX_SKEW and (m or not a) for a, m in zip(self.warm_up_skew, self.spread_mean))),
                    "warm_up_skew", f"one skew-normal shape per axis in −{MAX_SKEW:g} … {MAX_SKEW:g}, with a spread "
                    f"law only (0 on an axis without one), got {self.warm_up_skew!r}")
            require(len(self.sd_prior_count) == len(self.sd_prior_sd) in (0, self.dim) and all(
                is_finite_number(k) and 0 <= k <= MAX_NOMINAL and (k == 0 or (is_finite_number(sd) and 0 < sd < 1e6))
                for k, sd in zip(self.sd_prior_count, self.sd_prior_sd)), "sd_prior_count",
                f"per axis k pseudo-values (0 … {MAX_NOMINAL}) with their sd (> 0), or none, got "
                f"{self.sd_prior_count!r}, {self.sd_prior_sd!r}")
            if bounds:
                for name, values, low in bounds:
                    require(len(values) == self.dim and all(isinstance(v, (int, float)) and low <= v <= MAX_DRIFT
                                                            for v in values), name,
                            f"needs {self.dim} value(s) in {low:g} … {MAX_DRIFT:g} standard deviations, "
                            f"got {values!r}")
        except ConfigError as exc:
            raise DetectorConfigError(str(exc)) from None
        for name, gamma0, rho in (("gamma0", self.gamma0, 0.75), ("rho", 0.5, self.rho)):
            try:
                check_gain(gamma0, rho)
            except BiasEMError as exc:
                raise DetectorConfigError(f"{name}: {exc}") from None
        if self.pf is not None:
            try:
                check_pf(self.pf)
            except GLRError as exc:
                raise DetectorConfigError(f"pf: {exc}") from None

    def fingerprint(self) -> dict[str, Any]:
        return learned_part({**asdict(self), "transform_axes": list(self.transform_axes),
                             "sd_prior_count": list(self.sd_prior_count), "sd_prior_sd": list(self.sd_prior_sd)})

    def learning_values(self, stage: str, values: NDArray[np.float64]) -> NDArray[np.float64]:
        """The values ``stage``'s nominal is fitted to: the warm-up's with the sd prior (:func:`with_sd_prior`)."""
        return with_sd_prior(values, self.sd_prior_count, self.sd_prior_sd) if stage == "warm-up" else values

    def calibration(self, stage: str) -> dict[str, Any]:
        """Where the calibration of ``stage`` ("warm-up" | "steady") simulates the detector, as the
        :class:`~edge_monitor.stats.calibration.CalibrationJob` fields ``at``, ``drift_mean``, ``drift_sd``,
        ``wander`` (standard units) and ``transform`` (the learned transform it simulates; docs/DETECTION.md,
        "Two stages")."""
        if stage == "steady":
            return {"at": self.steady_at, "drift_mean": tuple(self.steady_drift_mean),
                    "drift_sd": tuple(self.steady_drift_sd), "wander": tuple(self.steady_wander),
                    "transform": self.steady_learned_transform, "spread_mean": (), "spread_sd": (), "skew": ()}
        return {"at": self.calibrate_at, "drift_mean": tuple(self.drift_mean), "drift_sd": tuple(self.drift_sd),
                "wander": tuple(self.warm_up_wander), "transform": "none", "spread_mean": tuple(self.spread_mean),
                "spread_sd": tuple(self.spread_sd), "skew": tuple(self.warm_up_skew)}

    def gaussian_settings(self, stage: str) -> GaussianSettings:
        """What a Gaussian calibration of ``stage`` ("warm-up" | "steady") simulates (:meth:`calibration`, the
        nominal's size and the detector's test; the shipped threshold table's key)."""
        at = self.calibration(stage)
        return GaussianSettings(self.n_nominal if stage == "warm-up" else self.steady_nominal, self.window,
                                self.gamma0, self.rho, self.direction, float(self.allowance), float(self.clip_sigma),
                                at["at"], at["drift_mean"], at["drift_sd"], at["wander"], at["transform"],
                                at["spread_mean"], at["spread_sd"], at["skew"])

    @property
    def steady_learned_transform(self) -> str:
        """The steady transform whose learning error the calibration simulates: ``steady_transform`` for a
        scalar detector that learns one, else "none" (a vector's exponents are not simulated: its calibration
        treats the transformed values as the Gaussian they were fitted to)."""
        learns = self.steady_transform != "none" and any(self.transform_axes or (True,))
        return self.steady_transform if learns and self.dim == 1 else "none"

    @property
    def budget(self) -> CalibrationBudget:
        return CalibrationBudget(draws=self.calibration_draws, max_steps=self.calibration_steps)


def learned_part(fingerprint: dict[str, Any]) -> dict[str, Any]:
    """A detector fingerprint, current or saved, without what is re-derived rather than learned (the target
    and :data:`CALIBRATION_KEYS`) and without the steady settings where they are the defaults (with
    ``transform_axes``: states saved before these settings existed still match)."""
    learned = {k: v for k, v in fingerprint.items() if k != "arl0" and k not in CALIBRATION_KEYS
               and not (k in SD_PRIOR_KEYS and not v)}       # none: states saved before the prior existed match
    return without_default_steady(learned, ("transform_axes",))


def without_default_steady(fingerprint: dict[str, Any], also: tuple[str, ...] = ()) -> dict[str, Any]:
    """``fingerprint`` without :data:`STEADY_LEARNED` (and ``also``) where those are the shipped defaults."""
    if tuple(fingerprint.get(key) for key in STEADY_LEARNED) != STEADY_DEFAULTS[1:]:
        return fingerprint
    return {k: v for k, v in fingerprint.items() if k not in STEADY_LEARNED and k not in also}
