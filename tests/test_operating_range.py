"""The operating conditions learned with the nominals, and the advisories outside them
(edge_monitor/pipeline/operating_range.py)."""

from __future__ import annotations

import json

import jsonschema
import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from edge_monitor.pipeline.operating_range import ENTER_CYCLES, RETURN_CYCLES, OperatingRange
from edge_monitor.records import Advisory
from edge_monitor.schemas import load_schema


def _learned(loads: list[float], temperatures: list[float]) -> OperatingRange:
    rng = OperatingRange()
    for k, (load, temp) in enumerate(zip(loads, temperatures)):
        rng.update({"load": load, "motor_temperature": temp}, collecting=True, fitted=k == len(loads) - 1)
    return rng


def test_the_range_is_that_of_the_cycles_the_nominal_was_learned_from() -> None:
    rng = _learned([0.3, 0.5, 0.7], [40.0, 42.0, 41.0])
    assert rng.section({"load": 0.5, "motor_temperature": 41.0}) == {
        "covariates": {"load": 0.5, "motor_temperature": 41.0},
        "learned": {"load": [0.3, 0.7], "motor_temperature": [40.0, 42.0]}, "outside": []}


def test_a_load_beyond_the_margin_enters_and_leaves_once() -> None:
    rng = _learned([0.3, 0.5, 0.7], [40.0, 42.0, 41.0])
    assert rng.update({"load": 0.74, "motor_temperature": 41.0}, False, False) == []    # inside the 0.04 margin
    for _ in range(ENTER_CYCLES - 1):                        # outside, said once it stays there
        assert rng.update({"load": 0.9, "motor_temperature": 41.0}, False, False) == []
        assert rng.section({"load": 0.9})["outside"] == ["load"]      # each cycle's own section says so at once
    events = rng.update({"load": 0.9, "motor_temperature": 41.0}, False, False)
    assert [(e.covariate, e.state, e.learned) for e in events] == [("load", "entered", (0.3, 0.7))]
    assert rng.update({"load": 0.95, "motor_temperature": 41.0}, False, False) == []    # still outside: no new event
    assert rng.section({"load": 0.95})["outside"] == ["load"]
    for _ in range(RETURN_CYCLES - 1):                       # back inside: said once it stays there
        assert rng.update({"load": 0.6, "motor_temperature": 41.0}, False, False) == []
    assert rng.section({"load": 0.6})["outside"] == []       # the cycle itself is inside
    assert [e.state for e in rng.update({"load": 0.6, "motor_temperature": 41.0}, False, False)] == ["left"]


def test_a_new_load_range_that_overlaps_the_learned_one_is_one_advisory_not_a_flapping_one() -> None:
    """Learned at 0.3 … 0.7, then 0.6 … 1.0: a quarter of the cycles fall inside again; one "entered"
    and no "left" while the new range lasts, one "left" once the old one is back for good."""
    rng = _learned([0.3, 0.5, 0.7], [40.0, 42.0, 41.0])
    new_range = [0.6 + 0.4 * ((k * 0.618) % 1.0) for k in range(200)]
    states = [e.state for load in new_range for e in rng.update({"load": load, "motor_temperature": 41.0}, False, False)]
    assert states == ["entered"]
    states = [e.state for _ in range(RETURN_CYCLES) for e in rng.update({"load": 0.5}, False, False)]
    assert states == ["left"]


def test_detectors_that_fit_one_after_the_other_learn_one_range() -> None:
    """The wear detector fits first, the KL ones a few cycles later: the range is the whole period."""
    rng = OperatingRange()
    loads = [0.31, 0.69, 0.5, 0.45, 0.52, 0.48]
    for k, load in enumerate(loads):
        rng.update({"load": load, "motor_temperature": 40.0}, collecting=True, fitted=k in (3, 5))
    rng.update({"load": 0.5, "motor_temperature": 40.0}, collecting=False, fitted=False)
    assert rng.section({})["learned"]["load"] == [0.31, 0.69]


def test_a_new_nominal_replaces_the_range_and_a_reset_forgets_it() -> None:
    rng = _learned([0.3, 0.7], [30.0, 35.0])
    rng.update({"load": 0.5, "motor_temperature": 40.0}, collecting=False, fitted=False)   # monitoring
    for k, temp in enumerate([50.0, 52.0, 51.0]):          # the steady nominal, learned warm
        rng.update({"load": 0.5, "motor_temperature": temp}, collecting=True, fitted=k == 2)
    events = [e for _ in range(ENTER_CYCLES)                                           # cold after a stop
              for e in rng.update({"load": 0.5, "motor_temperature": 33.0}, False, False)]
    assert [(e.covariate, e.state) for e in events] == [("motor_temperature", "entered")]
    rng.reset()
    assert rng.update({"load": 2.0, "motor_temperature": 0.0}, False, False) == []


def test_unknown_covariates_are_ignored_and_the_state_round_trips() -> None:
    rng = _learned([0.3, 0.7], [30.0, 35.0])
    rng.update({"load": None, "motor_temperature": float("nan")}, False, False)
    rng.update({"load": 1.0, "motor_temperature": 33.0}, False, False)
    again = OperatingRange.from_state(json.loads(json.dumps(rng.state_dict())))
    assert again.state_dict() == rng.state_dict()
    assert OperatingRange.from_state({"learned": {"load": ["x", 1]}, "outside": ["load"]}).state_dict() == {
        "learned": {}, "collecting": {}, "outside": [], "inside_run": {}, "was_collecting": False, "entering": {},
        "usual": {}}
    rng.update({"load": 1.0, "motor_temperature": 33.0}, False, False)     # a second cycle outside: counted
    assert OperatingRange.from_state(json.loads(json.dumps(rng.state_dict()))).entering == {"load": 2}


@given(st.dictionaries(st.text(max_size=12), st.one_of(st.none(), st.floats(), st.lists(st.floats(), max_size=3),
                                                        st.text(max_size=5)), max_size=4))
def test_any_saved_state_restores_without_error(state: dict) -> None:
    OperatingRange.from_state({"learned": state, "collecting": state, "outside": list(state)})


def test_the_advisory_says_what_it_is_and_fits_its_shipped_schema() -> None:
    record = Advisory("r1", 2, 700, "operating_range", "entered", "load", 0.93, (0.3, 0.7),
                      utc="2026-11-26T10:00:00Z").to_dict()
    assert record["advisory"] == "operating_range" and record["state"] == "entered"
    assert "not wear" in record["message"] and record["learned"] == [0.3, 0.7]
    jsonschema.validate(record, load_schema("advisory"))
    with pytest.raises(jsonschema.ValidationError):
        jsonschema.validate({**record, "state": "raised"}, load_schema("advisory"))


def test_the_usual_warming_path_widens_the_learned_temperatures_and_makes_no_advisory():
    """While the joint warms up (``usual``), each temperature it reaches widens the learned range: a joint that
    warmed 35 → 58 °C and comes back from a stop at 36 °C is on its usual path, no advisory; one hotter than
    ever (a hot day: 70 °C) is news. A load never learned is news whatever the temperature."""
    rng = _learned([0.3, 0.7], [34.0, 36.0])
    events = []
    for t in np.linspace(36.0, 58.0, 200):
        events += rng.update({"load": 0.5, "motor_temperature": float(t)}, False, False, usual=("motor_temperature",))
    assert events == [] and rng.learned["motor_temperature"].hi == pytest.approx(58.0)
    assert rng.update({"load": 0.5, "motor_temperature": 36.0}, False, False) == []
    hot = [e for _ in range(ENTER_CYCLES) for e in rng.update({"load": 0.5, "motor_temperature": 70.0}, False, False)]
    assert [(e.covariate, e.state) for e in hot] == [("motor_temperature", "entered")]
    heavy = [e for _ in range(ENTER_CYCLES)
             for e in rng.update({"load": 0.95, "motor_temperature": 40.0}, False, False, usual=("motor_temperature",))]
    assert ("load", "entered") in [(e.covariate, e.state) for e in heavy]
    again = OperatingRange.from_state(json.loads(json.dumps(rng.state_dict())))
    assert again.usual["motor_temperature"].hi == pytest.approx(58.0)


def test_one_cycle_of_scatter_beyond_the_margin_is_not_news():
    """A warming joint's motor temperature scatters ≈ 3 °C per cycle: a single cycle 4.6 °C above the highest
    learned (found on a healthy 200-cycle replay, seed 98, joint 5 at cycle 157: 56.6 °C against 33.8 … 52)
    makes no advisory, and neither do isolated spikes every other cycle; a hall that stays hotter does."""
    rng = _learned([0.3, 0.7], [33.8, 52.0])
    rng.update({"load": 0.5, "motor_temperature": 56.6}, False, False)
    assert rng.section({"motor_temperature": 56.6})["outside"] == ["motor_temperature"]
    events = [e for k in range(40)
              for e in rng.update({"load": 0.5, "motor_temperature": 58.0 if k % 2 else 47.0}, False, False)]
    assert events == []
    events = [e for _ in range(ENTER_CYCLES) for e in rng.update({"load": 0.5, "motor_temperature": 60.0}, False, False)]
    assert [(e.covariate, e.state, e.value) for e in events] == [("motor_temperature", "entered", 60.0)]
