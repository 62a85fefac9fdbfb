"""Independent checks of the Gaussian calibration (docs/DETECTION.md, "The warm-up stage"): the run length detectors
deliver when their values follow a law in their nominal's learned units, simulated from the law's definition; the
tolerance a delivered run length is judged with; a detector after its learning values."""

from __future__ import annotations

import math
from typing import Callable

import numpy as np

from edge_monitor.stats.detector_config import DetectorConfig
from edge_monitor.stats.gaussian_calibration import GaussianBudget, GaussianSettings, threshold
from edge_monitor.stats.glr_gaussian import GaussianBatchGLR
from edge_monitor.stats.sequential_detector import Decision, SequentialDetector


def delivered_in_learned_units(settings: GaussianSettings, h: float, detectors: int, cycles: int,
                                seed: int, draw: Callable[[np.random.Generator, int], np.ndarray] | None = None
                                ) -> tuple[float, int]:
    """Measured ARL0 of ``detectors`` scalar detectors whose values follow ``settings``' law in their nominal's
    learned units (written here from its definition, plain draws from another seed): each detector's nominal
    is N(0, 1), its stream μ + r·e with μ ~ N(drift_mean, drift_sd²), r ~ N(spread_mean, spread_sd²) and e
    standard normal (or ``draw(rng, detectors)``, unit-variance values of another law), every alarm
    acknowledged."""
    rng = np.random.default_rng(seed)
    draw = draw or (lambda g, n: g.standard_normal((n, 1)))
    mean = settings.drift_mean[0] + settings.drift_sd[0] * rng.standard_normal((detectors, 1))
    spread = np.maximum(settings.spread_mean[0] + settings.spread_sd[0] * rng.standard_normal((detectors, 1)), 0.05)
    ones = np.ones((detectors, 1))
    glr = GaussianBatchGLR(np.zeros((detectors, 1)), np.ones((detectors, 1, 1)), settings.window, settings.gamma0,
                           settings.rho, (np.full((detectors, 1), -np.inf), settings.allowance * ones),
                           (-settings.clip_sigma * ones, settings.clip_sigma * ones))
    alarms = 0
    for _ in range(cycles):
        alarm = glr.update(mean + spread * draw(rng, detectors)) >= h
        alarms += int(alarm.sum())
        if alarm.any():
            glr.restart(alarm)
    return detectors * cycles / max(alarms, 1), alarms


#: The tests' calibration budget (the defaults: 256 nominals × 4 streams × 2 000 cycles).
BUDGET = GaussianBudget()


def delivered_tolerance(settings: GaussianSettings, corr: tuple[tuple[float, ...], ...], target: float, alarms: int,
                        budget: GaussianBudget = BUDGET) -> float:
    """3 standard errors of log(delivered / target): the calibration's (h_se times the slope of log ARL0
    in h, from the thresholds of target and e·target) and the measurement's (1/√alarms)."""
    low, high = threshold(settings, corr, target, budget), threshold(settings, corr, math.e * target, budget)
    slope = 1.0 / (high.threshold - low.threshold)
    return 3.0 * math.hypot(slope * low.h_se, 1.0 / math.sqrt(max(alarms, 1)))


def learned_detector(config: DetectorConfig, seed: int) -> tuple[SequentialDetector, Decision]:
    """A detector with ``config`` after 60 standard normal values, and its last decision."""
    det = SequentialDetector(config)
    for i, v in enumerate(np.random.default_rng(seed).normal(size=60)):
        decision = det.update(v, i)
    return det, decision
