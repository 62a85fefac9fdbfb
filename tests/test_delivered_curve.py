"""studies.delivered (tools/studies/delivered_curve.py): a detector path replayed against many thresholds, alarms restarting it as
an acknowledge does."""

from __future__ import annotations

import copy
import sys
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).resolve().parent.parent / "tools" / "studies"))

from edge_monitor.config import config_from_mapping  # noqa: E402
from studies.delivered import (  # noqa: E402
    THRESHOLDS,
    Tally,
    check_variant,
    replay_joint,
    statistic_paths,
    summary,
    variant_job,
)
from studies.statistics import poisson_interval  # noqa: E402


@pytest.mark.parametrize("k,mean", [(0, 1.0), (3, 6.6), (40, 33.0)])
def test_poisson_interval_holds_the_ratio(k: int, mean: float) -> None:
    lo, hi = poisson_interval(k, mean)
    assert lo <= k / mean <= hi
    assert lo == 0.0 if k == 0 else lo > 0.0


def test_summary_pools_by_stage() -> None:
    tallies = {"steady/wear": Tally(1000, {100.0: 12}), "steady/kl_raw": Tally(3000, {100.0: 18}),
               "warm-up/wear": Tally(500, {100.0: 0})}
    rows = {(r["group"], r["target"]): r for r in summary(tallies, (100.0,))}
    pooled = rows[("steady/all", 100.0)]
    assert pooled["exposure"] == 4000 and pooled["crossings"] == 30 and pooled["due"] == 40.0
    assert pooled["ratio"] == pytest.approx(0.75)
    assert rows[("warm-up/all", 100.0)]["ratio"] == 0.0


def _gaussian_rows(n: int, seed: int) -> list[dict]:
    """A joint's kept series made of iid Gaussian detector inputs and no temperature (no steady stage)."""
    rng = np.random.default_rng(seed)
    values = rng.normal(size=(n, 3)) * [1.0, 0.3, 0.3] + [0.0, -3.0, -3.5]
    return [{"cycle": c, "wear_score": float(w), "kl_raw": float(np.exp(r)), "kl_weighted": float(np.exp(k)),
             "motor_temperature": None} for c, (w, r, k) in enumerate(values)]


def test_a_stop_holds_the_kl_detectors_in_the_replay_as_in_the_agent() -> None:
    """The robot's stops reach the replay as the agent sees them: after a 16-hour stop the KL detectors and the
    joint vector hold for ``pause_hold_cycles`` cycles (a plant week's replay without them alarmed on kl_raw
    right after its stops at 10⁷), the wear score does not."""
    decision = config_from_mapping({"decision": {"arl0_cycles": 1.0e7}}).decision
    rows = _gaussian_rows(400, 4)
    inputs = {p.quantity: len(p.inputs) for p in statistic_paths(rows, decision)}
    stopped = {p.quantity: len(p.inputs) for p in statistic_paths(rows, decision, {300: 16 * 3600.0})}
    assert stopped["wear"] == inputs["wear"]
    for q in ("kl_raw", "kl_weighted", "joint"):
        assert inputs[q] - stopped[q] == decision.pause_hold_cycles, q


def test_alarms_restart_the_statistic_like_an_acknowledge() -> None:
    """The path's GLR from fresh over its own inputs gives the statistics the agent reported, and at a
    threshold the path never reaches, no alarm; at one inside its range, alarms, each followed by a
    restart (so fewer alarms than cycles at or above the level)."""
    decision = config_from_mapping({"decision": {"arl0_cycles": 1.0e7}}).decision
    paths = statistic_paths(_gaussian_rows(600, 3), decision)
    wear = next(p for p in paths if p.quantity == "wear")
    glr = copy.deepcopy(wear.glr)
    glr.restart()
    replayed = np.array([glr.update_statistic(y) for y in wear.inputs])
    assert len(replayed) == len(wear.inputs) > 400
    np.testing.assert_allclose(replayed, wear.statistics, rtol=1e-12, atol=1e-12)   # the agent's own path
    assert wear.alarms(float(replayed.max()) + 1.0) == 0
    level = float(np.quantile(replayed, 0.9))
    assert 0 < wear.alarms(level) < np.count_nonzero(replayed >= level)


def test_boundary_calibration_runs_quieter_than_the_nominal_one_on_the_same_paths() -> None:
    """Inputs at the learned nominal itself: calibrated at the allowance boundary (+0.75 σ, the warm-up's
    default) the wear score runs below its stated rate; the same paths with the thresholds calibrated at
    the nominal alarm more, at both targets."""
    rows = _gaussian_rows(4000, 7)
    counts = {}
    for at in ("boundary", "nominal"):
        decision = config_from_mapping({"decision": {"arl0_cycles": 1.0e7, "calibrate_at": at}}).decision
        tallies = replay_joint(rows, decision, (50.0, 200.0))
        assert not any(key.startswith("steady/") for key in tallies)
        counts[at] = tallies["warm-up/wear"]
    exposure = counts["boundary"].exposure
    assert exposure > 3000
    assert counts["boundary"].crossings[50.0] < exposure / 50.0
    for target in (50.0, 200.0):
        assert counts["nominal"].crossings[target] > counts["boundary"].crossings[target]


def test_a_variant_may_change_the_calibration_only() -> None:
    base = config_from_mapping({}).decision
    check_variant(base, config_from_mapping({"decision": {"steady_drift": {"kl_raw": [0.1, 0.09]}}}).decision, "ok")
    deeper = config_from_mapping({"decision": {"calibrate_at": "healthy_drift", "calibration_draws": 512,
                                               "calibration_steps": 4000}}).decision
    check_variant(base, deeper, "ok")          # how much is simulated does not change a path either
    job = variant_job(statistic_paths(_gaussian_rows(300, 5), config_from_mapping(
        {"decision": {"arl0_cycles": 1.0e7}}).decision)[0].job, "warm-up", deeper.detector_config("wear"))
    assert job.at == "healthy_drift" and job.budget == deeper.detector_config("wear").budget
    for other in ({"allowance": 0.5}, {"steady_transform": "none"}, {"window": 50}):
        with pytest.raises(ValueError, match="a variant may only change"):
            check_variant(base, config_from_mapping({"decision": other}).decision, "bad")


def test_a_replay_that_alarms_is_refused() -> None:
    """A target the paths reach would latch a detector and cut its path: the tool says so."""
    decision = config_from_mapping({"decision": {"arl0_cycles": 1.0e7}}).decision
    rows = _gaussian_rows(300, 5)
    for row in rows[150:]:
        row["wear_score"] = 50.0                                   # far beyond anything learned
    with pytest.raises(RuntimeError, match="alarmed at cycle"):
        statistic_paths(rows, decision)


def test_the_command_refuses_a_bad_variant_with_a_message_before_replaying(capsys) -> None:
    from delivered_curve import main

    assert main(["--fleet", "101", "--plant", "--variant", "bad:decision.allowance=0.5"]) == 2
    assert "a variant may only change" in capsys.readouterr().err


def test_a_scalar_gaussian_threshold_is_computed_once_per_setting_and_is_the_agents() -> None:
    """Thresholds of scalar Gaussian nominals depend on their number of values and the settings only, so
    the tool computes them once: the same as each job's own calibration, for two nominals of one length."""
    rows = _gaussian_rows(300, 5)
    jobs = [p.job for p in statistic_paths(rows, config_from_mapping({"decision": {"arl0_cycles": 1.0e7}}).decision)
            if p.quantity == "wear"]
    first = jobs[0]
    other = replace(first, nominal=tuple((v[0] * 2.0 + 1.0,) for v in first.nominal))
    targets = (100.0, 1000.0)
    THRESHOLDS.clear()
    got = [THRESHOLDS.thresholds(job, targets) for job in (first, other)]
    assert len(THRESHOLDS) == 1 and got[0] == got[1]
    assert got[1] == {t: replace(other, arl0=t).run().threshold for t in targets}
