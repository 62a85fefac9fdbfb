"""The shipped threshold table (edge_monitor/stats/threshold_table.py): the joint vector reads it by the
correlation of its KL axes, the scalars as before, and what it states is delivered."""

from __future__ import annotations

import itertools
import math
from dataclasses import replace

import numpy as np
import pytest

from edge_monitor.pipeline.detectors import DecisionConfig
from edge_monitor.stats.calibration import calibrate
from edge_monitor.stats.gaussian_calibration import GaussianSettings
from edge_monitor.stats.glr_gaussian import GaussianBatchGLR
from edge_monitor.stats.threshold_table import (
    entries_by_key,
    entry_rho,
    entry_settings,
    key,
    lookup,
    tabulated_correlation,
)

JOINT = DecisionConfig().detector_config("joint")
WARM_UP = GaussianSettings(JOINT.n_nominal, JOINT.window, JOINT.gamma0, JOINT.rho, JOINT.direction,
                           float(JOINT.allowance), float(JOINT.clip_sigma), JOINT.calibrate_at,
                           tuple(JOINT.drift_mean), tuple(JOINT.drift_sd))
#: The warm-up calibrated at the allowance boundary (the option ``calibrate_at = "boundary"``): one setting for
#: the scalars and the joint vector.
BOUNDARY = GaussianSettings(JOINT.n_nominal, JOINT.window, JOINT.gamma0, JOINT.rho, JOINT.direction,
                            float(JOINT.allowance), float(JOINT.clip_sigma), "boundary")
STEADY = GaussianSettings(JOINT.steady_nominal, JOINT.window, JOINT.gamma0, JOINT.rho, JOINT.direction,
                          float(JOINT.allowance), float(JOINT.clip_sigma), JOINT.steady_at,
                          tuple(JOINT.steady_drift_mean), tuple(JOINT.steady_drift_sd), tuple(JOINT.steady_wander))


def _corr(rho: float, wear: tuple[float, float] = (0.0, 0.0)) -> tuple[tuple[float, ...], ...]:
    return ((1.0, wear[0], wear[1]), (wear[0], 1.0, rho), (wear[1], rho, 1.0))


def _entries(settings: GaussianSettings) -> list[dict]:
    return entries_by_key()[key(settings, 3)]


@pytest.mark.parametrize("settings", [WARM_UP, STEADY], ids=["warm-up", "steady"])
def test_the_joint_vector_is_tabulated_over_its_kl_correlation(settings: GaussianSettings) -> None:
    """Every tabulated ρ reads its own entry; between two, the linear interpolation; below the lowest
    (a negative correlation) the lowest's larger threshold; a correlation that is not a number, nothing."""
    entries = _entries(settings)
    rhos = [entry_rho(e) for e in entries]
    assert len(rhos) >= 3 and rhos[0] == 0.0 and rhos == sorted(rhos)
    k = entries[0]["arl0"].index(10_000.0)
    for e, rho in zip(entries, rhos):
        found = lookup(settings, 10_000.0, tabulated_correlation(rho, 3))
        assert found is not None and found.method == "table"
        assert found.threshold == pytest.approx(e["threshold"][k]) and found.h_se == pytest.approx(e["h_se"][k])
    middle = 0.5 * (rhos[1] + rhos[2])
    found = lookup(settings, 10_000.0, _corr(middle))
    assert found is not None
    assert found.threshold == pytest.approx(0.5 * (entries[1]["threshold"][k] + entries[2]["threshold"][k]))
    negative = lookup(settings, 10_000.0, _corr(-0.4))
    assert negative is not None and negative.threshold == pytest.approx(entries[0]["threshold"][k])
    assert lookup(settings, 10_000.0, _corr(math.nan)) is None


def test_the_threshold_falls_with_the_kl_correlation_so_the_lowest_is_cautious() -> None:
    """With H0's nearest point in the nominal's metric a shift along the correlation is explained by H0,
    so correlated axes need a lower threshold, never a higher one (within the stated errors)."""
    for settings in (WARM_UP, STEADY):
        entries = _entries(settings)
        for e in entries[1:]:
            for h, se, h0, se0 in zip(e["threshold"], e["h_se"], entries[0]["threshold"], entries[0]["h_se"]):
                assert h <= h0 + 3 * math.hypot(se, se0)


def test_the_scalar_and_the_vector_entries_of_the_same_settings_are_apart() -> None:
    """The boundary option's settings are the same for the scalars and the joint vector; the dimension keeps
    them apart."""
    scalar, vector = lookup(BOUNDARY, 10_000.0), lookup(BOUNDARY, 10_000.0, _corr(0.0))
    assert scalar is not None and vector is not None and vector.threshold > scalar.threshold + 1.0


def test_the_agents_joint_vector_reads_the_table_in_no_time() -> None:
    """A 3-d Gaussian nominal at the joint vector's shipped warm-up settings: read, not simulated."""
    rng = np.random.default_rng(3)
    values = rng.multivariate_normal([1.0, -4.0, -3.5], [[0.3, 0.0, 0.0], [0.0, 0.2, 0.12], [0.0, 0.12, 0.25]],
                                     size=JOINT.n_nominal)
    found = calibrate(values, "gauss", JOINT.window, 10_000.0, JOINT.gamma0, JOINT.rho, direction=JOINT.direction,
                      allowance=JOINT.allowance, clip_sigma=JOINT.clip_sigma, at=JOINT.calibrate_at,
                      drift_mean=JOINT.drift_mean, drift_sd=JOINT.drift_sd)
    assert found.cpu_s == 0.0 and found.h_se is not None
    rho = float(np.corrcoef(values, rowvar=False)[1, 2])
    expected = lookup(WARM_UP, 10_000.0, _corr(rho))
    assert expected is not None and found.threshold == expected.threshold


def _one_value_statistic(corr: np.ndarray, value: np.ndarray) -> float:
    """The joint vector's statistic after one value (standard units) on a fresh detector with nominal
    N(0, corr): the value winsorised at ±3σ, its first SA-EM step γ0·e, H0's nearest point in the
    nominal's metric."""
    sd = np.ones((1, 3))
    glr = GaussianBatchGLR(np.zeros((1, 3)), corr[None], JOINT.window, JOINT.gamma0, JOINT.rho,
                           (np.full((1, 3), -np.inf), JOINT.allowance * sd), (-JOINT.clip_sigma * sd,
                                                                                JOINT.clip_sigma * sd))
    return float(glr.update(value[None])[0])


@pytest.mark.parametrize("settings", [WARM_UP, STEADY], ids=["warm-up", "steady"])
def test_one_winsorised_value_cannot_raise_a_joint_alarm_on_the_default_budget(settings: GaussianSettings) -> None:
    """The largest statistic one value can give (any corner of the ±3σ clip box; correlations from
    independent to a healthy joint's most extreme) stays below a lower bound of the joint vector's
    threshold for the default budget's ARL0: its tabulated value less 3 standard errors, or, where that
    extrapolation is too uncertain to say anything (the warm-up), the threshold of a shorter run length
    read directly from the simulation less 3 of its standard errors (thresholds grow with ARL0)."""
    arl0 = DecisionConfig().arl0
    entries = _entries(settings)
    for wear_kl, kl in ((0.0, 0.0), (0.3, 0.7), (-0.42, 0.86), (0.0, 0.9)):
        corr = np.array([[1.0, wear_kl, wear_kl], [wear_kl, 1.0, kl], [wear_kl, kl, 1.0]])
        found = lookup(settings, arl0, tuple(map(tuple, corr)))
        assert found is not None
        direct = [lookup(settings, t, tuple(map(tuple, corr))) for t, m in zip(entries[0]["arl0"], entries[0]["method"])
                  if t <= arl0 and m == "simulated"]
        bound = max([found.threshold - 3 * found.h_se] + [d.threshold - 3 * d.h_se for d in direct if d])
        worst = max(_one_value_statistic(corr, 3.0 * np.array(signs))
                    for signs in itertools.product((-1.0, 1.0), repeat=3))
        assert worst < bound, (corr, worst, bound, found)


def test_the_table_tool_can_recompute_one_quantitys_entry_alone() -> None:
    """``--quantity wear --stage steady --only scalar`` selects the steady wear score's entry and nothing
    else (a deeper simulation of one entry, docs/DETECTION.md "Thresholds")."""
    import sys
    from pathlib import Path

    sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tools" / "studies"))
    from threshold_table import wanted

    from edge_monitor.pipeline.detectors import DecisionConfig

    wear = DecisionConfig().detector_config("wear")
    one = wanted("scalar", [], "steady", "wear")
    assert [(s.n0, s.at, s.drift_mean, s.drift_sd, dim) for s, dim, _ in one] == \
        [(wear.steady_nominal, wear.steady_at, tuple(wear.steady_drift_mean), tuple(wear.steady_drift_sd), 1)]
    assert len(wanted("scalar", [], "steady")) > 1
    assert {dim for _, dim, _ in wanted("vector", [0.0, 0.5], "steady", "joint")} == {3}


def test_the_steady_scalars_are_tabulated_with_their_transforms_learning_error_and_old_jobs_re_derive() -> None:
    """A steady scalar detector learns a Yeo–Johnson transform before its Gaussian: its calibration simulates
    the exponent's learning error (``transform``), and the table holds those settings, so no agent simulates
    at run time; the joint vector's calibration does not (stated in docs/DETECTION.md). A calibration job
    saved before the field existed reads as "none" and counts as calibrated elsewhere: restored, its
    threshold is re-derived for the current settings."""
    from edge_monitor.stats.calibration import CalibrationBudget, CalibrationJob
    from edge_monitor.stats.detector_state import recalibrated

    config = DecisionConfig()
    for quantity in ("wear", "kl_raw", "kl_weighted"):
        d = config.detector_config(quantity)
        at = d.calibration("steady")
        assert at["transform"] == "yeo-johnson" and d.calibration("warm-up")["transform"] == "none"
        assert lookup(d.gaussian_settings("steady"), 1e6) is not None, quantity
    # The exponent's learning error makes a detector louder, so its threshold is higher than the same setting's
    # without a transform, for every tabulated steady scalar setting that has both.
    pairs = 0
    for entries in entries_by_key().values():
        settings = entry_settings(entries[0])
        if settings.transform == "yeo-johnson" and len(entries[0]["correlation"]) == 1:
            without = lookup(replace(settings, transform="none"), 1e6)
            if without is not None:
                pairs += 1
                assert lookup(settings, 1e6).threshold > without.threshold, settings
    assert pairs >= 3
    assert JOINT.calibration("steady")["transform"] == "none"
    job = CalibrationJob(((0.0,), (1.0,), (2.0,)), "gauss", 100, 1e4, 0.6, 1.0, "recursive", CalibrationBudget(),
                         **config.detector_config("wear").calibration("steady"))
    old = {k: v for k, v in job.to_dict().items() if k != "transform"}
    assert CalibrationJob.from_dict(job.to_dict()) == job
    assert CalibrationJob.from_dict(old).transform == "none"
    assert recalibrated(CalibrationJob.from_dict(old), config.detector_config("wear").calibration("steady"))
