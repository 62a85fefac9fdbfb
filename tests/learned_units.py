"""The detectors' delivered run length when their values follow a law in their nominal's learned units, simulated
from the law's definition (an independent check of the Gaussian calibration's fleet; docs/DETECTION.md, "The warm-up
stage")."""

from __future__ import annotations

from typing import Callable

import numpy as np

from edge_monitor.stats.gaussian_calibration import GaussianSettings
from edge_monitor.stats.glr_gaussian import GaussianBatchGLR


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
