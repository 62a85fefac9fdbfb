"""The false-alarm budget per robot and period: its split over the detectors, the measured cycle rate,
and thresholds re-derived on the same nominals when that rate moves (edge_monitor/pipeline/cycle_rate.py,
docs/DETECTION.md, "The false-alarm budget")."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from edge_monitor.config import AgentConfig, config_from_mapping
from edge_monitor.errors import ConfigError
from edge_monitor.pipeline.cycle_rate import HOUR_S, RATE_TOLERANCE, BudgetRate, CycleRate
from edge_monitor.pipeline.detectors import DecisionConfig
from edge_monitor.stats.detector_config import DetectorConfig
from edge_monitor.stats.sequential_detector import SequentialDetector

DAY_S = 24 * HOUR_S
ROOT = Path(__file__).resolve().parents[1]


# ---------------------------------------------------------------- the budget and its split
def test_default_budget_is_one_false_alarm_per_robot_year() -> None:
    d = DecisionConfig()
    assert (d.false_alarms_per_robot, d.budget_period, d.budget_joints) == (1.0, "year", 6)
    assert d.joints_per_robot is None                               # not stated: 6, or the listed/mapped joints
    assert d.detectors_per_robot == 6 * 4
    assert d.arl0 == pytest.approx(300 * 365.25 * 24)             # 2.63e6 cycles per detector
    assert "1 false alarm(s) per robot-year" in d.budget_text


@pytest.mark.parametrize("period, days", [("day", 1), ("week", 7), ("month", 365.25 / 12), ("year", 365.25)])
def test_budget_periods_and_rates(period: str, days: float) -> None:
    d = DecisionConfig(false_alarms_per_robot=2.0, budget_period=period, cycles_per_day=120.0)
    assert d.arl0 == pytest.approx(120 * days * 24 / 2)
    assert d.arl0_for(240.0) == pytest.approx(2 * d.arl0)          # twice the cycles, twice the run length


def test_fixed_arl0_overrides_the_budget() -> None:
    d = DecisionConfig(arl0_cycles=1e4)
    assert d.arl0 == d.arl0_for(9_999.0) == 1e4
    assert "1e+04 cycles per detector" in d.budget_text


def test_listed_joints_split_the_budget_unless_said_otherwise() -> None:
    assert config_from_mapping({"joints": [0, 1, 2]}).decision.joints_per_robot == 3
    said = config_from_mapping({"joints": [0, 1, 2], "decision": {"joints_per_robot": 6}})
    assert said.decision.joints_per_robot == 6


def test_mapped_joints_split_the_budget_unless_said_otherwise() -> None:
    """A 3-joint mapping: each detector gets a twelfth of the robot's budget (3 joints × 4), not a 24th; a config
    that lists joints or states joints_per_robot keeps its own split."""
    import tomllib

    from edge_monitor.pipeline.agent_config import config_for
    from protocol.signal_mapping import mapping_from_dict

    path = ROOT / "protocol" / "mappings" / "foreign_robot.toml"
    data = tomllib.loads(path.read_text(encoding="utf-8"))
    data["joint"] = {k: v for k, v in data["joint"].items() if int(k) < 3}      # a 3-axis robot's mapping
    data.get("cycles", {}).pop("reference_joint", None)
    mapping = mapping_from_dict(data, path)
    assert len(mapping.joints) == 3
    mapped = config_for(AgentConfig(), mapping).decision
    assert (mapped.budget_joints, mapped.detectors_per_robot) == (3, 12)
    assert mapped.arl0 == pytest.approx(DecisionConfig().arl0 / 2)      # half the run length of a 6-joint share
    said = config_from_mapping({"decision": {"joints_per_robot": 6}})
    assert config_for(said, mapping).decision.budget_joints == 6
    listed = config_from_mapping({"joints": [0, 1]})
    assert config_for(listed, mapping).decision.budget_joints == 2


@pytest.mark.parametrize("table, field", [
    ({"budget_period": "fortnight"}, "decision.budget_period"),
    ({"false_alarms_per_robot": 0.0}, "decision.false_alarms_per_robot"),
    ({"false_alarms_per_robot": 1e-4}, "decision.false_alarms_per_robot"),    # 2.6e10 cycles: not calibrated
    ({"cycles_per_day": -3.0}, "decision.cycles_per_day"),
    ({"joints_per_robot": 0}, "decision.joints_per_robot"),
    ({"false_alarms_per_year": 12.0}, "decision.false_alarms_per_year"),      # the old per-detector key
])
def test_bad_budgets_are_config_errors(table: dict, field: str) -> None:
    with pytest.raises(ConfigError, match=field.replace(".", r"\.")):
        config_from_mapping({"decision": table})


# ---------------------------------------------------------------- the measured cycle rate
def test_cycle_rate_counts_the_last_24_complete_hours() -> None:
    counter = CycleRate()
    every = 300.0                                     # a cycle every 5 min: 288 a day
    rates = [counter.update(1_000.0 + k * every) for k in range(int(2 * DAY_S / every))]
    first = next(i for i, r in enumerate(rates) if r is not None)
    assert first * every >= DAY_S                      # nothing before a full day was seen
    assert first * every <= DAY_S + 2 * HOUR_S
    assert all(r == 288 for r in rates[first:])        # 12 cycles in each complete hour


def test_cycle_rate_sees_a_stop_and_restarts_on_a_clock_going_back() -> None:
    counter = CycleRate()
    for k in range(int(DAY_S / 600) + 12):             # a day and 2 h at 6 cycles an hour
        counter.update(k * 600.0)
    assert counter.rate == 144
    t = DAY_S + 2 * HOUR_S + 12 * HOUR_S               # the robot stood still for 12 h: of the last 24
    assert counter.update(t) == 6 * 12                 # complete hours, 12 saw cycles
    assert counter.update(t - 2 * HOUR_S) is None      # a clock 2 h back: counting starts again


@given(st.lists(st.floats(allow_nan=True, allow_infinity=True, width=64), max_size=200))
@settings(max_examples=200, deadline=None)
def test_cycle_rate_takes_any_clock(times: list[float]) -> None:
    counter = CycleRate()
    for t in times:
        rate = counter.update(t)
        assert rate is None or (math.isfinite(rate) and 0 <= rate <= len(times))
    restored = CycleRate.from_state(counter.state_dict())
    assert restored.state_dict() == counter.state_dict() and restored.rate == counter.rate


@pytest.mark.parametrize("state", [{}, {"counts": [0] * 3, "hour": 1, "first": 0},
                                   {"counts": [-1] * 25, "hour": 1, "first": 0},
                                   {"counts": [0] * 25, "hour": 1, "first": 5},
                                   {"counts": [0] * 25, "hour": None, "first": 0}])
def test_damaged_cycle_rate_state_is_refused(state: dict) -> None:
    with pytest.raises(ValueError):
        CycleRate.from_state(state)
    budget = BudgetRate(DecisionConfig())
    budget.load_state({"counter": state, "basis": None})               # a warning: measured again
    assert budget.counter.rate is None and not budget.measured


def _run_day(budget: BudgetRate, per_day: float, start: float = 0.0, days: float = 1.1) -> list[float]:
    every = DAY_S / per_day
    return [arl0 for k in range(int(days * per_day))
            if (arl0 := budget.update(start + k * every)) is not None]


def test_budget_rate_rederives_only_outside_the_tolerance() -> None:
    decision = DecisionConfig(cycles_per_day=300.0)
    inside = BudgetRate(decision)
    assert _run_day(inside, 300 * (1 + RATE_TOLERANCE) * 0.96) == []       # 20 % more: thresholds stay
    assert inside.arl0 == decision.arl0 and not inside.measured
    outside = BudgetRate(decision)
    changes = _run_day(outside, 480.0)                                       # 60 % more
    assert changes == [pytest.approx(decision.arl0_for(480.0))]
    assert outside.measured and outside.basis == 480 and outside.rederived == 1
    again = BudgetRate(decision)
    again.load_state(outside.state_dict())                                  # a restart keeps the measurement
    assert again.arl0 == outside.arl0 and again.measured


def test_a_fixed_arl0_is_never_rederived() -> None:
    budget = BudgetRate(DecisionConfig(arl0_cycles=1e4))
    assert _run_day(budget, 5_000.0) == [] and budget.arl0 == 1e4


# ---------------------------------------------------------------- thresholds re-derived on the same nominal
def _learned(arl0: float, seed: int = 1) -> SequentialDetector:
    det = SequentialDetector(DetectorConfig(n_nominal=60, arl0=arl0, direction="increase", allowance=0.75,
                                            clip_sigma=3.0))
    for cycle, value in enumerate(np.random.default_rng(seed).normal(size=61)):
        det.update(value, cycle)
    return det


def test_retarget_gives_the_threshold_a_fresh_calibration_would() -> None:
    det = _learned(1e4)
    low = det.threshold
    assert det.retarget(2.6e6)
    det.update(0.0, 100)                                  # the new threshold is adopted
    fresh = _learned(2.6e6)
    assert det.threshold == fresh.threshold > low         # deterministic: same nominal, same target
    assert det.calibration is not None and det.calibration.arl0 == 2.6e6
    assert not det.retarget(2.6e6)                         # the same target: nothing to do


def test_retarget_survives_a_restart() -> None:
    det = _learned(1e4)
    det.retarget(5e4)
    det.update(0.0, 100)
    restored = SequentialDetector.from_state(det.config, det.state_dict())
    assert restored.arl0 == 5e4 and restored.threshold == det.threshold
    assert restored.retarget(1e4)
    restored.update(0.0, 101)
    assert restored.threshold == _learned(1e4).threshold


def test_a_state_saved_with_another_target_is_not_relearned() -> None:
    det = _learned(1e4)
    state = det.state_dict()
    state["config"] = {**state["config"], "arl0": 1e4}        # as states saved before the budget existed
    other = DetectorConfig(n_nominal=60, arl0=2.6e6, direction="increase", allowance=0.75, clip_sigma=3.0)
    restored = SequentialDetector.from_state(other, state)
    assert restored.state == "monitoring" and restored.threshold == det.threshold


def test_unstated_joints_split_the_budget_over_the_joints_seen() -> None:
    """Native frames state no joint count: the budget follows the joints seen (6 before any); a stated
    ``joints_per_robot`` and a fixed ``arl0_cycles`` never move."""
    decision = DecisionConfig()
    budget = BudgetRate(decision)
    assert budget.joints == 6 and budget.arl0 == decision.arl0
    assert budget.count_joints(1) == pytest.approx(decision.arl0 / 6)
    assert budget.count_joints(1) is None                                      # the same count: nothing to do
    assert budget.count_joints(3) == pytest.approx(decision.arl0 / 2) and budget.joints == 3
    assert budget.count_joints(7) == pytest.approx(decision.arl0 * 7 / 6)      # a 7-axis robot: a 28th each
    assert budget.counters()["budget_joints"] == 7
    stated = BudgetRate(DecisionConfig(joints_per_robot=6))
    assert stated.count_joints(2) is None and stated.joints == 6
    fixed = BudgetRate(DecisionConfig(arl0_cycles=1e4))
    assert fixed.count_joints(2) is None and fixed.arl0 == 1e4
