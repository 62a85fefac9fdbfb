"""The simulator's plant timeline: load range, ambient, payload error, σl and stops at given cycles —
parsed and validated with errors naming the field, in effect at the right cycles, the same on the frame
path and the cycle-level fast path, with the lubricant cooling exactly during a stop and the controller's
tick and timestamps moving on by it."""

from __future__ import annotations

import json
import logging
import math
import threading
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from test_sim_support import collect, decode, run_on_virtual_bus

from protocol import frames as pf
from sim_controller.cli import main
from sim_controller.config import SimConfig, SimConfigError
from sim_controller.controller import STATUS_EVERY, Controller, statuses_between, stop_ticks
from sim_controller.cycle_mode import cycle_signals
from sim_controller.output import run
from sim_controller.scenario import (
    ScenarioError,
    load_scenario,
    packaged_scenarios,
    scenario_config,
    scenario_from_mapping,
)
from sim_controller.timeline import EVENT_KEYS, PlantEvent, TimelineError, merge_timelines, parse_event

SMALL = dict(joints=2, speeds=(10.0, 100.0), plateau_time=0.3, pause_time=0.1)
#: 56 h at 500 Hz is 100.8 M ticks: the 24-bit tick of the status frames wraps six times.
WEEKEND_H = 56.0


def _timeline_toml(tmp_path: Path, text: str) -> Path:
    path = tmp_path / "s.toml"
    path.write_text("[simulation]\ncycles = 10\n\n" + text)
    return path


# -- parsing and validation ---------------------------------------------------------------------


def test_scenario_timeline_tables_become_events_in_effect_from_their_cycle(tmp_path):
    path = _timeline_toml(tmp_path, """
[[timeline]]
cycle = 3
load_range = [0.6, 1.0]
payload_error = 0.1
[[timeline]]
cycle = 6
stop_hours = 56
ambient = 25
load_std = 0.05
""")
    config = SimConfig(**load_scenario(path))
    assert config.timeline == (PlantEvent(3, load_range=(0.6, 1.0), payload_error=0.1),
                               PlantEvent(6, ambient=25.0, load_std=0.05, stop_hours=56.0))
    expected = {0: ((0.3, 0.7), 30.0, 0.0, 0.1), 2: ((0.3, 0.7), 30.0, 0.0, 0.1), 3: ((0.6, 1.0), 30.0, 0.1, 0.1),
                5: ((0.6, 1.0), 30.0, 0.1, 0.1), 6: ((0.6, 1.0), 25.0, 0.1, 0.05), 9: ((0.6, 1.0), 25.0, 0.1, 0.05)}
    for cycle, (load_range, ambient, payload_error, load_std) in expected.items():
        c = config.conditions(cycle)
        assert (c.load_range, c.ambient, c.payload_error, c.load_std) == (load_range, ambient, payload_error,
                                                                          load_std), cycle
    assert [config.stop_hours(c) for c in range(10)] == [0.0] * 6 + [56.0] + [0.0] * 3


@pytest.mark.parametrize("table, message", [
    ("[[timeline]]\ncycle = 3\nstop_hours = -1\n", "scenario.timeline[0].stop_hours: must be > 0"),
    ("[[timeline]]\ncycle = 3\nload_range = [0.8, 0.2]\n", "scenario.timeline[0].load_range: need 0 ≤ LOW ≤ HIGH"),
    ("[[timeline]]\ncycle = 3\nload_range = 0.5\n", "scenario.timeline[0].load_range: need 0 ≤ LOW ≤ HIGH"),
    ("[[timeline]]\ncycle = 3\nambient = 200\n", "scenario.timeline[0].ambient: must be −40 … 150 °C"),
    ("[[timeline]]\ncycle = 3\npayload_error = 0.9\n", "scenario.timeline[0].payload_error: must be −0.5 … 0.5"),
    ("[[timeline]]\ncycle = 3\nload_std = \"high\"\n", "scenario.timeline[0].load_std: expected a finite number"),
    ("[[timeline]]\ncycle = 3\nwear = 5\n", "scenario.timeline[0]: unknown field(s) ['wear']"),
    ("[[timeline]]\nload_std = 0.2\n", "scenario.timeline[0].cycle: required"),
    ("[[timeline]]\ncycle = -2\nload_std = 0.2\n", "scenario.timeline[0].cycle: expected a test-cycle number ≥ 0"),
    ("[[timeline]]\ncycle = 3\n", "scenario.timeline[0]: changes nothing"),
    ("[[timeline]]\ncycle = 5\nambient = 20\n[[timeline]]\ncycle = 7\nambient = 25\n"
     "[[timeline]]\ncycle = 7\nstop_hours = 2\n", "scenario.timeline[2].cycle: 7 must be greater than"),
    ("[[timeline]]\ncycle = 5\nambient = 20\n[[timeline]]\ncycle = 9\nstop_hours = 1e6\n",
     "scenario.timeline[1].stop_hours: must be > 0 and ≤ 8760 h"),
    ("timeline = 3\n", "scenario.timeline: expected [[timeline]] tables"),
])
def test_bad_timeline_tables_name_the_field(tmp_path, capsys, table, message):
    path = tmp_path / "s.toml"
    path.write_text(table)
    with pytest.raises(ScenarioError) as error:
        load_scenario(path)
    assert message in str(error.value)
    with pytest.raises(SystemExit) as exit_info:                      # the user's view: usage error, exit 2
        main(["record", "--out", str(tmp_path / "x.blf"), "--scenario", str(path)])
    assert exit_info.value.code == 2 and message in capsys.readouterr().err
    assert not (tmp_path / "x.blf").exists()


_VALUES = st.one_of(st.integers(-3, 10**7), st.floats(allow_nan=True, allow_infinity=True), st.booleans(),
                    st.text(max_size=4), st.lists(st.one_of(st.floats(-0.5, 1.5), st.integers(-1, 2), st.text(max_size=2)),
                                                  max_size=3), st.none(), st.dictionaries(st.text(max_size=2),
                                                                                          st.integers(), max_size=1))
_TABLES = st.lists(st.one_of(st.dictionaries(st.sampled_from((*EVENT_KEYS, "stop", "Cycle")), _VALUES, max_size=4),
                             _VALUES), max_size=5)


@settings(max_examples=300, deadline=None)
@given(tables=st.one_of(_TABLES, _VALUES))
def test_random_timeline_tables_give_a_scenario_error_or_a_valid_config(tables):
    try:
        kwargs = scenario_from_mapping({"timeline": tables})
    except ScenarioError as exc:
        assert str(exc).startswith("scenario.timeline"), exc
        return
    config = SimConfig(**kwargs)                                        # never a late SimConfigError
    assert [e.cycle for e in config.timeline] == sorted({e.cycle for e in config.timeline})


@settings(max_examples=300, deadline=None)
@given(text=st.one_of(st.text(max_size=30), st.from_regex(
    r"\A[0-9]{1,4}:(load_range=[0-9.]{1,4}:[0-9.]{1,4}|ambient=-?[0-9.]{1,4}|stop_hours=[0-9.e-]{1,5}|"
    r"load_std=[0-9.]{1,4}|payload_error=-?[0-9.]{1,4})(,(ambient|stop_hours)=[0-9.]{1,3}){0,2}\Z")))
def test_command_line_events_parse_or_say_what_is_wrong(text):
    try:
        event = parse_event(text)
    except TimelineError as exc:
        assert str(exc).startswith("event") and repr(text) in str(exc), exc
        return
    assert event.cycle == int(text.partition(":")[0])


def test_command_line_events_merge_over_the_scenario_timeline(tmp_path):
    base = (PlantEvent(3, load_range=(0.6, 1.0)), PlantEvent(8, stop_hours=12.0))
    extra = (parse_event("8:ambient=35,stop_hours=2"), parse_event("5:payload_error=-0.1"),
             parse_event("3:load_range=0.4:0.8"))
    assert merge_timelines(base, extra) == (PlantEvent(3, load_range=(0.4, 0.8)), PlantEvent(5, payload_error=-0.1),
                                            PlantEvent(8, ambient=35.0, stop_hours=2.0))
    with pytest.raises(SimConfigError, match=r"timeline\[1\].cycle: 3 must be greater"):
        SimConfig(timeline=(PlantEvent(5, ambient=20.0), PlantEvent(3, ambient=25.0)))
    with pytest.raises(TimelineError, match="timeline event.stop_hours"):
        PlantEvent(2, stop_hours=math.nan)


def test_packaged_scenarios_load_by_name_and_describe_the_plant_week():
    assert packaged_scenarios() == ["load_step", "load_step_wear", "mild_load_step", "plant_week"]
    step = SimConfig(**load_scenario("load_step"))
    assert step.conditions(999).load_range == (0.3, 0.7) and step.conditions(1000).load_range == (0.6, 1.0)
    assert SimConfig(**load_scenario("mild_load_step.toml")).conditions(1000).load_range == (0.4, 0.8)
    week = SimConfig(**load_scenario("plant_week"))
    stops = {e.cycle: e.stop_hours for e in week.timeline if e.stop_hours}
    assert week.cycles == 4400
    assert stops == {400: 0.5, 800: 16.0, 1200: 0.5, 1600: 16.0, 2000: 0.5, 2400: 16.0, 2800: 0.5, 3200: 16.0,
                     3600: 0.5, 4000: 64.0}
    assert week.conditions(1999).load_range == (0.3, 0.7) and week.conditions(2000).load_range == (0.5, 0.9)
    assert [week.conditions(c).ambient for c in (2599, 2600, 3199, 3200)] == [30.0, 36.0, 36.0, 30.0]
    with pytest.raises(ScenarioError, match="packaged: load_step, load_step_wear, mild_load_step, plant_week"):
        load_scenario("plant_month")


def test_a_study_config_puts_seed_and_length_over_the_scenario():
    config = scenario_config("load_step", {"seed": 7, "joints": 3, "cycles": None}, fallback={"cycles": 200},
                             wear_ramps=("2:100:200:0:60",))
    assert (config.seed, config.joints, config.cycles) == (7, 3, 1300)
    assert config.conditions(1000).load_range == (0.6, 1.0) and config.wear_profile(2).wear(200) == 60.0
    assert scenario_config(None, {"seed": 1}, fallback={"cycles": 200}).cycles == 200


# -- the plant as simulated ---------------------------------------------------------------------


def _truth_by_cycle(records: list[dict], joint: int = 0) -> dict[int, dict]:
    return {r["cycle"]: r for r in records if r["joint"] == joint}


def test_a_load_step_moves_each_cycles_load_and_nothing_else_drawn():
    """The load magnitude is U(range) per joint and cycle from the same random numbers with or without the
    step, so after a step of the same width each |τl| is the old one + 0.3; the estimate follows with the
    payload error of the event."""
    base = SimConfig(cycles=6, seed=4, **SMALL)
    stepped = base.with_(timeline=(PlantEvent(3, load_range=(0.6, 1.0), payload_error=0.2),))
    before, after = Controller(base), Controller(stepped)
    for _ in before.simulated_cycles():
        pass
    for _ in after.simulated_cycles():
        pass
    for a, b in zip(before.truth_records(), after.truth_records()):
        assert (a["joint"], a["cycle"], a["p2p_delay"], a["model_error"]) == (b["joint"], b["cycle"], b["p2p_delay"],
                                                                              b["model_error"])
        if b["cycle"] < 3:
            assert b["load"] == a["load"] and b["load_range"] == [0.3, 0.7] and b["payload_error"] == 0.0
        else:
            assert abs(b["load"]) == pytest.approx(abs(a["load"]) + 0.3, abs=1e-12)
            assert 0.6 <= abs(b["load"]) <= 1.0 and b["load_range"] == [0.6, 1.0] and b["payload_error"] == 0.2
            noise = a["load_estimate"] - a["load"]
            assert b["load_estimate"] == pytest.approx(1.2 * b["load"] + noise, abs=1e-12)


@pytest.mark.parametrize("acceleration", [1.0, 10.0])
def test_the_lubricant_cools_during_a_stop_as_the_exact_exponential(acceleration):
    """Hot joint (60 °C), ambient lowered to 20 °C for a 2 h stop before cycle 2: the temperature of cycle
    2 is ambient + (ξ − ambient)·exp(−A·t/τth) from the ξ the joint had at the end of cycle 1 (that of the
    same run without the stop), t the stop's length in the timestamps."""
    base = SimConfig(cycles=3, seed=2, start_temperature=60.0, min_temperature=0.0, time_acceleration=acceleration,
                     **SMALL)
    stopped = base.with_(timeline=(PlantEvent(2, stop_hours=2.0, ambient=20.0),))
    runs = []
    for config in (base, stopped):
        controller = Controller(config)
        for _ in controller.simulated_cycles():
            pass
        runs.append(_truth_by_cycle(controller.truth_records()))
    plain, cooled = runs
    gap_s = cooled[2]["t_start"] - cooled[1]["t_end"]
    assert gap_s == pytest.approx(2.0 * 3600.0, abs=1.0 / base.rate)
    expected = 20.0 + (plain[2]["temperature"] - 20.0) * math.exp(-acceleration * gap_s / base.thermal_time_constant)
    assert cooled[2]["temperature"] == pytest.approx(expected, rel=1e-12)
    assert plain[2]["temperature"] > 55.0 and cooled[2]["temperature"] < plain[2]["temperature"] - 5.0
    assert (cooled[2]["stop_hours"], cooled[2]["ambient"], cooled[1]["stop_hours"]) == (2.0, 20.0, 0.0)


def test_a_stop_moves_ticks_counters_and_timestamps_on_and_the_24_bit_tick_wraps():
    config = SimConfig(cycles=3, seed=1, timeline=(PlantEvent(2, stop_hours=WEEKEND_H),), **SMALL)
    controller = Controller(config)
    block = collect(controller.frames())
    decoded = decode(block)
    truth = _truth_by_cycle(controller.truth_records())
    gap = stop_ticks(WEEKEND_H, config.rate)
    assert gap == 100_800_000 > 6 * 2**24
    assert truth[2]["t_start"] - truth[1]["t_end"] == pytest.approx(gap / config.rate, abs=1e-6)
    status = np.flatnonzero(decoded.valid & (decoded.kind == pf.FrameKind.CONTROLLER_STATUS))
    cycles = decoded.cycle[status]
    first_after = status[cycles == 2][0]
    end_of_1 = int(round(truth[1]["t_end"] * config.rate))               # ticks run 0 … end_of_1 − 1 before
    first_status_tick = -(-(end_of_1 + gap) // STATUS_EVERY) * STATUS_EVERY      # every 10th tick
    assert first_status_tick > 6 * 2**24 and decoded.status_tick[first_after] == first_status_tick % 2**24
    sent_before = int(np.count_nonzero(cycles <= 1))
    assert decoded.counter[first_after] == (sent_before + statuses_between(end_of_1, gap)) % 16
    assert statuses_between(end_of_1, gap) == (end_of_1 + gap + STATUS_EVERY - 1) // STATUS_EVERY - sent_before
    motor = np.flatnonzero(decoded.valid & (decoded.kind == pf.FrameKind.MOTOR_STATE) & (decoded.joint == 0))
    steps = np.diff(block.timestamps[motor])
    k = int(np.argmax(steps))                          # the one long silence: the last sample before the stop
    assert steps[k] == pytest.approx((gap + 1) / config.rate, abs=1e-6)
    assert np.all(np.delete(steps, k) < 1.0)
    assert (decoded.counter[motor[k]], decoded.counter[motor[k + 1]]) == ((end_of_1 - 1) % 256,
                                                                          (end_of_1 + gap) % 256)


def test_frame_path_and_fast_path_carry_the_same_plant_across_a_load_step_and_a_stop():
    """Same seed and timeline: the fast path's truth equals the frame path's, and its signals are the
    frames' values (wire-quantised), ticks modulo the counters' ranges."""
    config = SimConfig(cycles=5, seed=9, timeline=(
        PlantEvent(2, load_range=(0.6, 1.0), payload_error=-0.1, load_std=0.2),
        PlantEvent(3, stop_hours=WEEKEND_H, ambient=35.0)), **SMALL)
    controller = Controller(config)
    decoded = decode(collect(controller.frames()))
    fast = list(cycle_signals(config))
    assert [t for s in fast for t in s.truth] == controller.truth_records()
    assert [t["load_range"] for t in controller.truth_records()[::2]] == [[0.3, 0.7]] * 2 + [[0.6, 1.0]] * 3
    assert [t["stop_hours"] for t in controller.truth_records()[::2]] == [0.0, 0.0, 0.0, WEEKEND_H, 0.0]
    status = decoded.valid & (decoded.kind == pf.FrameKind.CONTROLLER_STATUS)
    ticks = np.concatenate([s.status_ticks for s in fast])
    assert np.array_equal(decoded.status_tick[status], ticks % 2**24)
    assert np.array_equal(decoded.segment[status], np.concatenate([s.status_segments for s in fast]))
    for j in range(config.joints):
        motor = decoded.valid & (decoded.kind == pf.FrameKind.MOTOR_STATE) & (decoded.joint == j)
        joint = decoded.valid & (decoded.kind == pf.FrameKind.JOINT_STATUS) & (decoded.joint == j)
        signals = [s.joints[j] for s in fast]
        assert np.array_equal(decoded.counter[motor], np.concatenate([s.ticks for s in fast]) % 256)
        for frame_values, fast_values in (
                (decoded.torque[motor], [s.torque for s in signals]),
                (decoded.speed[motor], [s.speed for s in signals]),
                (decoded.load_estimate[joint], [s.load_estimate for s in signals]),
                (decoded.load_std[joint], [s.load_std for s in signals]),
                (decoded.motor_temperature[joint], [s.motor_temperature for s in signals])):
            np.testing.assert_allclose(frame_values, np.concatenate(fast_values), rtol=0, atol=1e-12)
    stds = np.concatenate([s.joints[0].load_std for s in fast])
    per_cycle = np.concatenate([np.full(s.status_ticks.size, s.cycle) for s in fast])
    assert np.allclose(stds[per_cycle < 2], 0.1, atol=pf.LOAD_STD_SCALE)
    assert np.allclose(stds[per_cycle >= 2], 0.2, atol=pf.LOAD_STD_SCALE)


# -- the command line ---------------------------------------------------------------------------


def test_record_with_a_scenario_timeline_and_events_writes_the_conditions_to_the_truth(tmp_path):
    path = _timeline_toml(tmp_path, "[[timeline]]\ncycle = 1\nload_range = [0.6, 1.0]\n"
                                    "[[timeline]]\ncycle = 2\nstop_hours = 3\n")
    truth = tmp_path / "t.jsonl"
    assert main(["record", "--out", str(tmp_path / "r.blf"), "--scenario", str(path), "--cycles", "3",
                 "--joints", "1", "--speeds", "10,100", "--plateau-time", "0.3", "--truth", str(truth),
                 "--event", "2:ambient=40", "--event", "1:load_range=0.5:0.9", "-q"]) == 0
    records = [json.loads(line) for line in truth.read_text().splitlines()[:-1]]
    assert [(r["load_range"], r["ambient"], r["stop_hours"]) for r in records] == [
        ([0.3, 0.7], 30.0, 0.0), ([0.5, 0.9], 30.0, 0.0), ([0.5, 0.9], 40.0, 3.0)]
    params = json.loads((tmp_path / "t.params.json").read_text())
    assert params["timeline"] == [{"cycle": 1, "load_range": [0.5, 0.9]},
                                  {"cycle": 2, "ambient": 40.0, "stop_hours": 3.0}]


def test_run_pauses_for_a_stop_at_most_max_pause_and_says_so(caplog):
    config = SimConfig(joints=1, cycles=2, speeds=(20.0,), plateau_time=0.2, seed=1,
                       timeline=(PlantEvent(1, stop_hours=10.0),))
    with caplog.at_level(logging.WARNING, logger="sim_controller"):
        summary, received = run_on_virtual_bus(config, "sim-test-stop", speedup=1e4, max_pause=0.05)
    assert received == summary.frames_sent > 0 and summary.cycles == 2
    assert any("plant stop of 10.00 h before cycle 1 would pause 4 s" in r.getMessage()
               and "pausing 0 s instead" in r.getMessage() for r in caplog.records), caplog.text


def test_a_stopped_run_ends_during_a_long_pause():
    """SIGTERM (``stop()``) is honoured while the sender waits out a plant stop, not hours later."""
    config = SimConfig(joints=1, cycles=2, speeds=(20.0,), plateau_time=0.2, seed=1,
                       timeline=(PlantEvent(1, stop_hours=100.0),))
    stop = threading.Event()
    timer = threading.Timer(0.5, stop.set)
    timer.start()
    try:
        summary = run(config, "virtual:sim-test-long-stop", speedup=100.0, stop=stop.is_set)
    finally:
        timer.cancel()
    assert summary.cycles <= 1 and summary.wall_s < DEFAULT_WAIT_BOUND_S


#: A bound far below the 600 s the 100 h stop would pause at 100× (cut to the default --max-pause).
DEFAULT_WAIT_BOUND_S = 120.0
