"""The joint vector's wear axis drawn from the wear score's own warm-up law on a joint without motor temperature
(docs/WITHOUT_MOTOR_TEMPERATURE.md): the fits of a vector with an axis in learned units, the threshold calibrated for
it and the run length it delivers on joints drawn from the law's definition, and which joints get it."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest
from learned_units import BUDGET
from numpy.typing import NDArray

from edge_monitor.pipeline.decision_config import DecisionConfig
from edge_monitor.pipeline.healthy_drift import WARM_UP_LAW, WARM_UP_LAW_FRICTION
from edge_monitor.stats.gaussian_calibration import GaussianBudget, GaussianSettings, balanced, simulate, threshold
from edge_monitor.stats.gaussian_fleet import fleet_detectors, skew_normal_standard
from edge_monitor.stats.learned_axes import independent_learned_axes, partly_learned_fits
from edge_monitor.stats.threshold_table import lookup, tabulated_correlation

LAW = WARM_UP_LAW_FRICTION["wear_score"]
#: The shipped warm-up joint vector of a joint with a motor temperature: learning error and healthy drift per axis.
WITH_MOTOR = GaussianSettings(60, 100, 0.6, 1.0, "increase", 0.75, 3.0, "healthy_drift", (0.05, 0.0, 0.0),
                              (0.26, 0.08, 0.08))
#: The same without motor temperature: the wear axis in learned units, from the wear score's own law.
WITHOUT_MOTOR = dataclasses.replace(WITH_MOTOR, drift_mean=(LAW[0], 0.0, 0.0), drift_sd=(LAW[1], 0.08, 0.08),
                                    spread_mean=(LAW[2], 0.0, 0.0), spread_sd=(LAW[3], 0.0, 0.0),
                                    skew=(LAW[5], 0.0, 0.0))
CORR = tabulated_correlation(0.5, 3)


def test_an_axis_in_learned_units_is_fitted_exactly_and_its_spread_drawn_without_bias() -> None:
    """The learned axis's fit is exact (mean 0, variance 1, no covariance with the others); the weighted spread
    draws have the law's mean and sd, the KL block's weighted fitted variances the true 1; tolerances 4 standard
    errors of each weighted mean."""
    n = 4096
    r = np.asarray(CORR)
    means, covs, weight, spread = partly_learned_fits(WITHOUT_MOTOR, np.arange(n), r, np.random.default_rng(5),
                                                      (0.0, 1.5, 3.0, 4.5))
    assert np.all(means[:, 0] == 0.0) and np.all(covs[:, 0, 0] == 1.0)
    assert np.all(covs[:, 0, 1:] == 0.0) and np.all(covs[:, 1:, 0] == 0.0) and np.all(spread[:, 1:] == 1.0)
    z = (spread[:, 0] - LAW[2]) / LAW[3]
    for value, expected in ((np.ones(n), 1.0), (z, 0.0), (z * z, 1.0), (covs[:, 1, 1], 1.0), (covs[:, 2, 2], 1.0),
                            (covs[:, 1, 2], r[1, 2])):
        assert abs(np.mean(weight * value) - expected) < 4 * np.std(weight * value) / math.sqrt(n), expected
    with pytest.raises(ValueError, match="one spread per axis"):
        partly_learned_fits(dataclasses.replace(WITHOUT_MOTOR, spread_mean=(LAW[2], 0.0), spread_sd=(LAW[3], 0.0),
                                                skew=()), np.arange(8), r, np.random.default_rng(5), (0.0,))


def test_several_learned_axes_draw_their_own_spreads_on_balanced_budgets() -> None:
    """Two learned axes: their spread draws differ from each other and from chunk to chunk (their own seeds); a
    learned axis is uncorrelated with the rest in the fits and the streams; a budget whose nominals do not hold whole
    sets of proposals is rounded up by :func:`balanced` and refused by the simulation; a law's length must be the
    vector's."""
    two = dataclasses.replace(WITHOUT_MOTOR, spread_mean=(LAW[2], 1.1, 0.0), spread_sd=(LAW[3], 0.1, 0.0))
    r = np.asarray(CORR)
    tilts = (0.0, 1.5, 3.0, 4.5)
    first = partly_learned_fits(two, np.arange(128), r, np.random.default_rng(5), tilts)[3]
    second = partly_learned_fits(two, np.arange(128, 256), r, np.random.default_rng(5), tilts)[3]
    z = [(first[:, 0] - LAW[2]) / LAW[3], (first[:, 1] - 1.1) / 0.1, (second[:, 1] - 1.1) / 0.1]
    assert abs(np.corrcoef(z[0], z[1])[0, 1]) < 0.5 and not np.allclose(z[1], z[2])
    assert independent_learned_axes(r, (0, 1))[1, 2] == 0.0 and independent_learned_axes(r, (0,))[1, 2] == r[1, 2]
    budget = GaussianBudget(nominals=96, streams=4, steps=200).tilted()
    assert balanced(WITHOUT_MOTOR, budget).nominals == 128 and balanced(two, budget).nominals == 256
    assert balanced(WITH_MOTOR, budget) == budget
    with pytest.raises(ValueError, match="multiple of 64"):
        simulate(WITHOUT_MOTOR, CORR, budget)
    with pytest.raises(ValueError, match="one spread per axis"):
        simulate(dataclasses.replace(WITHOUT_MOTOR, spread_mean=(LAW[2],), spread_sd=(LAW[3],), skew=()), CORR,
                 balanced(WITHOUT_MOTOR, budget))


def _delivered(settings: GaussianSettings, h: float, detectors: int, cycles: int, seed: int,
               wear_step: float = 0.0) -> tuple[float, NDArray[np.float64], float]:
    """Measured ARL0, alarms per detector and the mean first-alarm cycle of ``detectors`` joint vectors whose joints
    follow the no-motor-temperature law, written here from its definition with plain draws: the wear axis's nominal
    N(0, 1) exact, its values μ + r·e (μ ~ N(law mean, sd²), r ~ N(law spread, sd²), e skew-normal of the law's
    shape), moved ``wear_step`` learned sd up (a worn joint); the KL axes learned from 60 values of N(0, R) and
    drifting N(0, 0.08²) beyond them; every alarm acknowledged."""
    rng = np.random.default_rng(seed)
    r = np.asarray(CORR)
    chol = np.linalg.cholesky(r[1:, 1:])
    learning = rng.standard_normal((detectors, 60, 2)) @ chol.T
    kl_mean = learning.mean(axis=1)
    dev = learning - kl_mean[:, None, :]
    means = np.zeros((detectors, 3))
    covs = np.zeros((detectors, 3, 3))
    means[:, 1:], covs[:, 0, 0] = kl_mean, 1.0
    covs[:, 1:, 1:] = np.einsum("gni,gnj->gij", dev, dev) / 59
    glr = fleet_detectors(settings, means, covs, 1)           # as the agent builds them from its fits
    shift = np.stack([LAW[0] + LAW[1] * rng.standard_normal(detectors),
                      *(0.08 * rng.standard_normal((2, detectors)))], axis=1)
    spread = np.maximum(LAW[2] + LAW[3] * rng.standard_normal(detectors), 0.05)
    alarms, first = np.zeros(detectors), np.full(detectors, float(cycles))
    for t in range(cycles):
        kl = rng.standard_normal((detectors, 2)) @ chol.T
        wear = spread * skew_normal_standard(LAW[5], rng.standard_normal(detectors), rng.standard_normal(detectors))
        alarm = glr.update(np.column_stack([wear + wear_step, kl]) + shift) >= h
        first = np.where(alarm & (first == cycles), t, first)
        alarms += alarm
        if alarm.any():
            glr.restart(alarm)
    return detectors * cycles / max(float(alarms.sum()), 1.0), alarms, float(first.mean())


@pytest.mark.slow
def test_the_vector_calibrated_for_the_law_delivers_its_target_and_alarms_on_wear() -> None:
    """Both sides, on joints drawn from the no-motor-temperature law: the threshold calibrated for it delivers the
    target within 3 standard errors of the calibration's and the measurement's errors (its alarms clustered by
    joint); a threshold 1 nat lower delivers clearly less, a loud detector the measurement tells apart (with the
    learned sd's prior the law sits near the learning error and drift of a joint with a motor temperature, whose
    threshold delivered 0.89× here: no longer a loud one); and the calibrated one still finds a wear step of 3
    learned sd on the wear axis within a few cycles."""
    target = 1000.0
    found = threshold(WITHOUT_MOTOR, CORR, target, BUDGET)
    delivered, alarms, _ = _delivered(WITHOUT_MOTOR, found.threshold, 256, 6000, seed=91)
    high = threshold(WITHOUT_MOTOR, CORR, math.e * target, BUDGET)
    slope = 1.0 / (high.threshold - found.threshold)
    clustered = math.sqrt(float(np.var(alarms, ddof=1)) * alarms.size) / alarms.sum()    # alarms cluster by joint
    tolerance = 3.0 * math.hypot(slope * found.h_se, clustered)
    assert abs(math.log(delivered / target)) <= tolerance, (found, delivered, alarms.sum())
    loud = _delivered(WITHOUT_MOTOR, found.threshold - 1.0, 256, 6000, seed=92)[0]
    worn = _delivered(WITHOUT_MOTOR, found.threshold, 256, 200, seed=93, wear_step=3.0)[2]
    assert loud < target / 1.4
    assert worn < 20      # a 3 sd step gains ≈ (3 − 0.75)²/2 ≈ 2.5 nats a cycle: ≈ 2 cycles to a 4-nat threshold


def test_only_a_joint_without_motor_temperature_draws_its_wear_axis_from_the_law_and_it_is_tabulated() -> None:
    """The shipped decision gives the joint vector the law on its wear axis where the joint sends no motor
    temperature (and its KL axes their own laws), and the learning error with the healthy drift where it does; both read their thresholds from the
    shipped table at every target, the two apart at one per robot-week (the law, in units of the sd learned with its
    prior, against the learning error and a drift: lower since the prior, 2026-11-30 evening; higher before)."""
    c = DecisionConfig()
    without = c.detector_config("joint", friction_temperature=True).calibration("warm-up")
    with_motor = c.detector_config("joint").calibration("warm-up")
    kl_raw, kl_weighted = WARM_UP_LAW["kl_raw"], WARM_UP_LAW["kl_weighted"]    # its KL axes from their laws (12-01)
    assert without["spread_mean"] == (LAW[2], kl_raw[2], kl_weighted[2]) and without["skew"] == (LAW[5], 0.0, 0.0)
    assert without["drift_mean"] == (LAW[0], kl_raw[0], kl_weighted[0])
    assert without["drift_sd"] == (LAW[1], kl_raw[1], kl_weighted[1]) and without["wander"] == ()
    assert with_motor["spread_mean"] == () and with_motor["drift_mean"] == (0.05, 0.0, 0.0)
    shipped = dataclasses.replace(WITH_MOTOR, drift_mean=without["drift_mean"], drift_sd=without["drift_sd"],
                                  spread_mean=without["spread_mean"], spread_sd=without["spread_sd"],
                                  skew=without["skew"])
    assert lookup(shipped, c.arl0, CORR) is not None and lookup(WITH_MOTOR, c.arl0, CORR) is not None
    found, before = lookup(shipped, 50_400, CORR), lookup(WITH_MOTOR, 50_400, CORR)
    assert found is not None and before is not None
    assert abs(found.threshold - before.threshold) > 3 * math.hypot(found.h_se, before.h_se)
