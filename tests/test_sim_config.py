"""Simulator configuration: value parsers, wear-scenario properties, validation messages."""

from __future__ import annotations

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from sim_controller.config import (
    SimConfig,
    SimConfigError,
    parse_range,
    parse_speeds,
    wear_profiles_from_laws,
    wear_profiles_from_ramps,
)
from sim_controller.faults import RATE_KEYS, FaultSpec
from sim_controller.test_cycle import SEGMENT_PRODUCTION, build_cycle
from sim_controller.wear_scenarios import WearEvent, WearProfile, WearScenarioError, parse_wear_law, parse_wear_ramp

wear_level = st.floats(0.0, 100.0)
cycle = st.integers(0, 500)


@st.composite
def wear_events(draw):
    kind = draw(st.sampled_from(["ramp", "exponential", "power", "step", "replacement"]))
    start = draw(cycle)
    end = start + draw(st.integers(0, 300))
    return WearEvent(kind, start, end if kind in ("ramp", "exponential", "power") else None, draw(wear_level),
                     draw(wear_level), tau=draw(st.floats(0.5, 200.0)), exponent=draw(st.floats(0.05, 20.0)))


@settings(max_examples=100, deadline=None)
@given(initial=wear_level, events=st.lists(wear_events(), max_size=5), at=st.integers(0, 1000))
def test_wear_stays_within_0_and_100(initial, events, at):
    assert 0.0 <= WearProfile(initial, tuple(events)).wear(at) <= 100.0


@settings(max_examples=100, deadline=None)
@given(start=cycle, length=st.integers(1, 300), lo=wear_level, hi=wear_level, tau=st.floats(1e-3, 200.0))
def test_ramp_and_exponential_go_monotonically_from_start_to_end(start, length, lo, hi, tau):
    for kind in ("ramp", "exponential", "power"):
        exponent = min(max(tau / 10, 0.05), 20.0)
        profile = WearProfile(events=(WearEvent(kind, start, start + length, lo, hi, tau=tau, exponent=exponent),))
        values = [profile.wear(c) for c in range(start, start + length + 1)]
        assert values[0] == pytest.approx(lo) and values[-1] == pytest.approx(hi)
        step = [b - a for a, b in zip(values, values[1:])]
        assert all(s >= -1e-9 for s in step) if hi >= lo else all(s <= 1e-9 for s in step)


@settings(max_examples=50, deadline=None)
@given(st.dictionaries(st.sampled_from(RATE_KEYS), st.floats(0.0, 1.0), max_size=len(RATE_KEYS)))
def test_fault_spec_round_trips_through_its_text_form(rates):
    spec = FaultSpec(**rates)
    text = ",".join(f"{k}={v!r}" for k, v in spec.to_dict().items())
    assert FaultSpec.parse(text) == spec


def test_value_parsers():
    assert parse_range("30:70", "temperature_range") == (30.0, 70.0)
    assert parse_speeds("2.1, 8.7,15") == (2.1, 8.7, 15.0)
    assert parse_wear_ramp("all:10:20:0:35") == ("all", WearEvent("ramp", 10, 20, 0.0, 35.0))
    profiles = wear_profiles_from_ramps(["all:0:10:0:20", "1:5:6:20:40"], 2)
    assert profiles[0].wear(10) == 20.0 and profiles[1].wear(6) == 40.0
    with pytest.raises(SimConfigError, match="temperature_range: must be finite"):
        parse_range("nan:3", "temperature_range")
    with pytest.raises(WearScenarioError, match=r"wear_ramp: expected JOINT:START_CYCLE:END_CYCLE:FROM:TO"):
        parse_wear_ramp("0:1:2")


def test_wear_laws_from_the_command_line_take_every_kind_of_event_in_order():
    assert parse_wear_law("2:power:start=100,end=300,from=0,to=60,exponent=2") == (
        2, WearEvent("power", 100, 300, 0.0, 60.0, exponent=2.0))
    # a step at 50 followed by a slow ramp from there: the kinds compose as in a scenario file
    profile = wear_profiles_from_laws(["all:step:start=50,to=12", "1:ramp:start=50,end=150,from=12,to=32"], 2)
    assert profile[0].wear(49) == 0.0 and profile[0].wear(200) == 12.0
    assert profile[1].wear(100) == pytest.approx(22.0) and profile[1].wear(150) == 32.0
    assert WearProfile(events=(WearEvent("power", 0, 100, 0.0, 60.0, exponent=2.0),)).wear(50) == pytest.approx(15.0)
    for text, message in (("0:power", "expected JOINT:KIND:KEY=VALUE"), ("x:ramp:start=1,end=2", "JOINT must be"),
                          ("0:melt:start=1", "wear_law.kind"), ("0:ramp:start=1,to", "expected KEY=VALUE"),
                          ("0:ramp:start=1,end=x", "end needs a number"), ("0:ramp:start=5,end=1,to=3", "must be ≥ start"),
                          ("0:power:start=1,end=9,to=3,exponent=0", "exponent: must be 0.05 … 20")):
        with pytest.raises(WearScenarioError, match=message):
            parse_wear_law(text)
    with pytest.raises(SimConfigError, match="wear_law: unknown joint 3"):
        wear_profiles_from_laws(["3:step:start=1,to=5"], 2)


@pytest.mark.parametrize("kwargs, message", [
    (dict(joints=0), "joints:"), (dict(rate=10.0), "rate:"), (dict(speeds=()), "speeds:"),
    (dict(temperature_range=(50.0, 40.0)), "temperature_range: need LOW ≤ HIGH"),
    (dict(load_range=(-0.1, 0.5)), "load_range:"), (dict(variation=0.9), "vary:"),
    (dict(plateau_time=0.0), "plateau_time:"), (dict(p2p_delay=(0.05, 0.01)), "p2p_delay:"),
    (dict(time_acceleration=0.0), "time_acceleration:"), (dict(friction_model_error=-1e-3), "friction_model_error:"),
    (dict(speeds=(2.1, 8.7, 2.1)), "speeds: each speed level once"),
])
def test_config_validation_names_the_field(kwargs, message):
    with pytest.raises(SimConfigError, match=message):
        SimConfig(**kwargs)


def test_default_cycle_has_the_specified_shape():
    config = SimConfig()
    ref = build_cycle(config.speeds, config.rate, config.plateau_time, config.acceleration, config.pause_time,
                      0.05, config.production_speed)
    duration = ref.n / config.rate
    assert 30.0 <= duration <= 40.0                                   # ≈ 30–40 s per test cycle
    for k, v in enumerate(config.speeds):
        in_level = ref.segment == k + 1
        motion = in_level.sum() / config.rate
        assert 2 * config.plateau_time <= motion <= 2 * config.plateau_time + 4 * v / config.acceleration + 0.01
        at_plus = abs(ref.speed - v) < 1e-9
        assert at_plus.sum() / config.rate == pytest.approx(config.plateau_time, abs=2 / config.rate)
    assert abs(ref.angle[-1]) < 1e-9                                   # every cycle returns to its start angle
    production = ref.segment == SEGMENT_PRODUCTION
    assert production.any() and abs(ref.speed[production]).max() <= config.production_speed + 1e-9


def test_a_scenario_or_speeds_file_that_is_not_utf8_is_named(tmp_path):
    """Non-UTF-8 bytes in --scenario or --speeds-from gave "'utf-8' codec can't decode …" without the file."""
    from sim_controller.config import load_speeds_file
    from sim_controller.scenario import ScenarioError, load_scenario

    bad = tmp_path / "latin.toml"
    bad.write_bytes("name = \"Halle W\xe4rme\"\n".encode("latin-1"))
    with pytest.raises(ScenarioError, match="latin.toml is not UTF-8"):
        load_scenario(bad)
    speeds = tmp_path / "speeds.json"
    speeds.write_bytes(b'{"speeds": [2.1, 8.7]}')
    assert load_speeds_file(speeds) == (2.1, 8.7)
    speeds.write_bytes(b'\xff{"speeds": [2.1]}')
    with pytest.raises(SimConfigError, match="speeds.json is not UTF-8"):
        load_speeds_file(speeds)
