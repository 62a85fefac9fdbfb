"""Coverage of the detectors (edge_monitor/pipeline/coverage.py): what is counted, the shares, persistence."""

from __future__ import annotations

import json

import pytest
from hypothesis import given
from hypothesis import strategies as st

from edge_monitor.pipeline.coverage import REASONS, Coverage, DetectorCoverage, coverage_reason
from edge_monitor.records import Decision, to_json


def test_counting_starts_when_the_first_learning_ends():
    cov = DetectorCoverage(window=10)
    for reason in ["model"] * 20 + ["learning"] * 60:
        cov.update(reason)
    assert cov.cycles == 0 and cov.share is None and cov.recent is None
    for reason in ["calibrating", "tested", "tested", "held_warm", "tested"]:
        cov.update(reason)
    assert cov.cycles == 5 and cov.share == pytest.approx(3 / 5)
    assert cov.not_tested() == {"calibrating": 1, "held_warm": 1}
    for _ in range(3):                           # a relearn after the first learning counts against coverage
        cov.update("learning")
    assert cov.counts["learning"] == 3 and cov.share == pytest.approx(3 / 8)


def test_recent_share_is_over_the_window_only():
    cov = DetectorCoverage(window=10)
    for _ in range(50):
        cov.update("tested")
    for _ in range(4):
        cov.update("held_cold")
    assert cov.share == pytest.approx(50 / 54)
    assert cov.recent == pytest.approx(6 / 10)      # the last 10: 6 tested, 4 held


@given(st.lists(st.sampled_from(REASONS), max_size=400), st.integers(1, 50))
def test_shares_are_fractions_and_the_state_round_trips(reasons, window):
    cov = DetectorCoverage(window)
    for reason in reasons:
        cov.update(reason)
    for share in (cov.share, cov.recent):
        assert share is None or 0.0 <= share <= 1.0
    again = DetectorCoverage.from_state(json.loads(to_json(cov.state_dict())), window)
    assert again.summary() == cov.summary()


@pytest.mark.parametrize("damaged", [None, 3, {"counts": {"tested": -1}, "ring": [], "position": 0},
                                     {"counts": {}, "ring": [99] * 10, "position": 0},
                                     {"counts": {}, "ring": [0] * 9, "position": 0}])
def test_a_damaged_state_starts_afresh(damaged):
    cov = DetectorCoverage.from_state(damaged, window=10)
    assert cov.cycles == 0 and not cov.started


def test_unknown_reasons_and_windows_are_refused():
    with pytest.raises(ValueError, match="unknown coverage reason"):
        DetectorCoverage().update("sleeping")
    with pytest.raises(ValueError, match="window"):
        DetectorCoverage(window=0)


def test_the_reason_of_a_decision():
    monitoring = Decision("monitoring", statistic=0.3, threshold=5.0)
    assert coverage_reason(monitoring, learning=False, finite=True) == "tested"
    assert coverage_reason(monitoring, learning=True, finite=True) == "learning"     # the cycle that ends learning
    assert coverage_reason(Decision("learning"), learning=True, finite=True) == "learning"
    assert coverage_reason(Decision("monitoring", statistic=0.3), learning=False, finite=True) == "calibrating"
    assert coverage_reason(Decision("monitoring", threshold=5.0), learning=False, finite=False) == "no_value"
    assert coverage_reason(Decision("monitoring"), False, True, "held: motor temperature 60 °C above …") == "held_warm"
    assert coverage_reason(Decision("monitoring"), False, True, "held: motor temperature 20 °C below …") == "held_cold"


def test_joint_coverage_section_and_state():
    cov = Coverage(["wear", "kl_raw"], window=5)
    cov.update({"wear": "tested", "kl_raw": "learning"})
    cov.update({"wear": "tested", "kl_raw": "tested"})
    cov.update({"wear": "no_value", "kl_raw": "tested", "joint": "tested"})     # an unwatched name is ignored
    section = cov.section({"wear": "no_value", "kl_raw": "tested"})
    assert section == {"wear": {"status": "no_value", "share": pytest.approx(2 / 3), "recent": pytest.approx(2 / 3)},
                       "kl_raw": {"status": "tested", "share": 1.0, "recent": 1.0}}
    again = Coverage.from_state(["wear", "kl_raw"], json.loads(to_json(cov.state_dict())))
    assert again.summary() == cov.summary()
    assert Coverage.from_state(["wear"], {"window": -4}).window == 300


def test_the_agent_reports_coverage_in_every_symptom_and_in_health():
    """A 2-joint simulated robot on the fast path (60 cycles; detectors learn from 20 values): once a detector
    has left its first learning every symptom says it tested the cycle; the health record's counts agree with
    the last symptom's shares."""
    from edge_monitor.config import config_from_mapping
    from edge_monitor.offline.fast_path import run_cycles
    from edge_monitor.pipeline.agent import Agent
    from sim_controller.config import SimConfig
    from sim_controller.cycle_mode import cycle_signals

    agent = Agent(config_from_mapping({"decision": {"n_nominal": 20, "arl0_cycles": 1000.0}}))
    records = [s.to_dict() for s in run_cycles(agent, cycle_signals(SimConfig(joints=2, cycles=60, seed=3)))]
    assert {"wear", "kl_raw", "kl_weighted", "joint"} == set(records[-1]["coverage"])
    statuses = [r["coverage"]["wear"]["status"] for r in records if r["joint"] == 0]
    assert statuses[0] == "model" and "learning" in statuses and statuses[-1] == "tested"
    health = agent.health().counters["coverage"]
    for record in records[-2:]:
        for quantity, section in record["coverage"].items():
            counted = health[str(record["joint"])][quantity]
            assert section["share"] == pytest.approx(counted["share"]) and 0 < counted["cycles"] < 60
