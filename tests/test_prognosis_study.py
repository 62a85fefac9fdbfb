"""The prognosis study's own parts (docs/PROGNOSIS.md): the wear laws reach the critical wear when they say,
and Saxena et al.'s metrics score a perfect forecast as perfect and a wrong one as wrong."""

from __future__ import annotations

import pytest

from joint_model import CRITICAL_WEAR
from sim_controller.wear_scenarios import WearProfile
from studies.prognosis_fleet import LAWS, CycleRow, joint_law, robot_laws
from studies.prognosis_metrics import ForecastRow, covers, law_table, score_healthy, score_wearing


@pytest.mark.parametrize("law", LAWS)
@pytest.mark.parametrize("shape", [0.0, 0.5, 0.99])
def test_every_law_reaches_the_critical_wear_after_its_life(law, shape):
    joint = joint_law(law, onset=200, life=1000, shape=shape)
    profile = WearProfile(events=joint.events)
    assert profile.wear(199) == 0.0 and profile.wear(200) <= 14.0 + 1e-9       # a step goes to at most 14
    # the spans are rounded to whole cycles: the crossing lands within a few cycles of onset + life
    assert abs(joint.end_of_life - 1200) <= 3
    assert profile.wear(joint.end_of_life) >= CRITICAL_WEAR > profile.wear(joint.end_of_life - 1)
    values = [profile.wear(c) for c in range(200, joint.end_of_life + 1)]
    assert all(b >= a for a, b in zip(values, values[1:]))                      # wear never falls


def test_a_robot_takes_the_laws_in_turn_from_its_seed():
    assert [j.law for j in robot_laws(4801)] == [LAWS[(4801 + i) % 5] for i in range(6)]
    assert robot_laws(4801) == robot_laws(4801) and robot_laws(4801) != robot_laws(4802)


def _rows(end: int, alarm_at: int) -> list[CycleRow]:
    return [CycleRow(c, 34.0 * c, 35.0 * c / end, 0.0, 1.0, c >= alarm_at, False, False) for c in range(end + 10)]


def test_a_perfect_forecast_scores_perfectly_and_a_late_one_does_not():
    end, alarm = 500, 200
    rows = _rows(end, alarm)
    perfect = [ForecastRow(c, "forecast", (0.9 * (end - c), float(end - c), 1.1 * (end - c)), False, False)
               for c in range(alarm, end)]
    score = score_wearing("linear", rows, perfect)
    assert (score.first_alarm, score.end_of_life, score.forecasts) == (alarm, end, end - alarm)
    assert score.coverage == 1.0 and score.alpha_lambda is True and score.relative_accuracy == 1.0
    assert score.horizon_share == 1.0
    late = [ForecastRow(c, "forecast", (1.5 * (end - c), 2.0 * (end - c), 3.0 * (end - c)), False, False)
            for c in range(alarm, end)]
    score = score_wearing("linear", rows, late)
    assert score.coverage == 0.0 and score.alpha_lambda is False and score.relative_accuracy == 0.0
    table = law_table([score])
    assert table["linear"]["coverage"] == table["all"]["coverage"] == 0.0


def test_a_band_without_its_upper_end_holds_every_longer_life_and_no_trend_holds_none():
    assert covers(ForecastRow(0, "forecast", (10.0, 50.0, None), False, False), 1e6)
    assert not covers(ForecastRow(0, "forecast", (10.0, 50.0, None), False, False), 5.0)
    assert not covers(ForecastRow(0, "no_trend", None, True, False), 50.0)


def test_a_healthy_joint_counts_its_cycles_beyond_the_horizon_and_its_warnings():
    rows = [ForecastRow(0, "learning", None, True, False)] + \
           [ForecastRow(c, "no_trend", None, True, False) for c in range(1, 97)] + \
           [ForecastRow(c, "forecast", (1.0, 2.0, 3.0), False, c < 99) for c in range(97, 101)]
    score = score_healthy(rows)
    assert (score.cycles, score.beyond, score.warnings) == (100, 96, 1) and score.beyond_share == 0.96


def test_the_nominal_wear_coefficients_read_a_joint_with_its_own_as_the_truth_and_a_stronger_one_high():
    import dataclasses

    from joint_model.friction import DEFAULT_PARAMS
    from studies.prognosis_error_budget import nominal_equivalent

    grid, same = nominal_equivalent(DEFAULT_PARAMS)
    # the bounded search stops within 1e-4 of the optimum: a reading of the nominal joint is the truth
    assert same == pytest.approx(grid, abs=1e-3)
    stronger = dataclasses.replace(DEFAULT_PARAMS, fsw=DEFAULT_PARAMS.fsw * 1.08, fvw=DEFAULT_PARAMS.fvw * 1.08)
    grid, reads = nominal_equivalent(stronger)
    at = [float(reads[grid == w][0]) for w in (10.0, 20.0, 35.0)]
    # 8 % stronger wear friction reads higher, by at most the 8 % (the wear's Stribeck speed grows with it too)
    assert all(w < r <= 1.08 * w + 1e-3 for w, r in zip((10.0, 20.0, 35.0), at))


def test_synthetic_estimates_follow_the_reading_keep_the_gaps_and_the_bias_is_read_in_its_band():
    import numpy as np

    from studies.prognosis_error_budget import bias_in_band, synthetic_rows

    rows = [CycleRow(k, 60.0 * k, float(k), 0.0 if k % 5 else None, 0.0, False, k < 2, False) for k in range(40)]
    reading = (np.array([0.0, 100.0]), np.array([0.0, 110.0]))        # reads 10 % high
    out = synthetic_rows(rows, reading, np.random.default_rng(1))
    assert [r.estimate is None for r in out] == [r.estimate is None for r in rows]
    assert all(o.estimate == pytest.approx(1.1 * o.wear) for o in out if o.estimate is not None)
    truth = synthetic_rows(rows, None, np.random.default_rng(1))
    assert bias_in_band(truth) == pytest.approx(0.0)
    # mean of 0.1·w over the estimated cycles with w in 10 … 30
    kept = [k for k in range(10, 31) if k % 5]
    assert bias_in_band(out) == pytest.approx(0.1 * sum(kept) / len(kept))
    assert bias_in_band(out, (50.0, 60.0)) is None


def test_shuffled_errors_keep_their_values_within_their_wear_bins_or_over_the_life():
    import numpy as np

    from studies.prognosis_error_budget import shuffled_rows

    # wear 10 … 60, errors −3 … +3 (never clipped at 0), a gap every 9th cycle
    rows = [CycleRow(k, 60.0 * k, 10.0 + k / 4, (10.0 + k / 4 + (k % 7) - 3.0) if k % 9 else None, 1.0,
                     False, False, False) for k in range(200)]

    def errors(rs, keep=lambda r: True):
        return sorted(round(r.estimate - r.wear, 9) for r in rs if r.estimate is not None and keep(r))

    for width in (2.5, None):
        out = shuffled_rows(rows, np.random.default_rng(3), width)
        assert [r.estimate is None for r in out] == [r.estimate is None for r in rows]
        assert errors(out) == errors(rows)                                  # the same errors …
        assert [o.estimate for o in out] != [r.estimate for r in rows]      # … in another order
    out = shuffled_rows(rows, np.random.default_rng(3), 2.5)
    for b in range(4, 24):                                                 # … and none left its bin
        in_bin = lambda r, b=b: int(r.wear // 2.5) == b                    # noqa: E731
        assert errors(out, in_bin) == errors(rows, in_bin)
