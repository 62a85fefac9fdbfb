"""One alarm per fault through the real agent (frames → features → detectors → fault grouping → sinks
and run statistics), fixed seeds, both sides: a wear ramp seen by several detectors is one "raised"
record then "updated" ones (a healthy run of the same seed: none); a detector crossing again soon after
an acknowledgement is the same fault "chattering", with a shorter chatter window the same crossing is a
new fault; a restart from the state file keeps the open fault (without the saved fault it would raise a
second one); advisories are published and counted apart from alarms.

Short synthetic runs with small learning settings (10 nominal values, the asymptotic threshold at
Pf = 1e-4, no steady relearning): these tests are about grouping, not calibration."""

from __future__ import annotations

import dataclasses
import json

import jsonschema
import pytest
from test_agent_pipeline import feed, small_config

from edge_monitor.pipeline.agent import Agent
from edge_monitor.pipeline.fault_grouping import AlarmConfig
from edge_monitor.pipeline.state_store import StateStore
from edge_monitor.schemas import load_schema

from synthetic_frames import cycle_profile, make_frames

TICKS = cycle_profile((8.7, 41.7, 133.5))[0].size
ONSET = 14             # first worn cycle (the detectors have learned by then)


class Sink:
    """Every alarm and advisory record as published."""

    def __init__(self) -> None:
        self.alarms: list[dict] = []
        self.advisories: list[dict] = []

    def on_symptom(self, symptom) -> None: pass
    def on_alarm(self, alarm) -> None: self.alarms.append(json.loads(json.dumps(alarm.to_dict())))
    def on_advisory(self, advisory) -> None: self.advisories.append(advisory.to_dict())
    def on_health(self, health) -> None: pass
    def close(self) -> None: pass


def config(chatter_cycles: int = 20):
    base = small_config()
    return dataclasses.replace(base, kl=dataclasses.replace(base.kl, n_nominal_cycles=10),
                               decision=dataclasses.replace(base.decision, n_nominal=10, pf=1e-4, steady_relearn=False),
                               alarms=AlarmConfig(chatter_cycles))


def cycles(first: int, n: int, slope: float, seed: int = 9, temperature: float = 45.0):
    """Frames of cycles ``first`` … ``first + n - 1`` of joint 0, wear ``slope`` per cycle from ONSET on."""
    return make_frames(n, joints=(0,), wear=lambda j, c: max(0.0, slope * (c - ONSET)), seed=seed + first,
                       first_cycle=first, first_tick=first * TICKS,
                       motor_temperature=lambda c: 45.0 if c < ONSET + 10 else temperature)


def summary(records: list[dict]) -> list[tuple]:
    return [(r["state"], r["fault"], r["cycle"], [d["quantity"] for d in r["detectors"]]) for r in records]


def test_a_wear_ramp_seen_by_several_detectors_is_one_fault_updated_and_a_healthy_run_none():
    worn, healthy = Sink(), Sink()
    agents = Agent(config(), sinks=[worn]), Agent(config(), sinks=[healthy])
    for agent, slope in zip(agents, (1.0, 0.0)):
        feed(agent, cycles(0, ONSET + 16, slope))
    schema = load_schema("alarm")
    for record in worn.alarms:
        jsonschema.validate(record, schema)
    assert summary(worn.alarms) == [
        ("raised", "robot1/0/23", 23, ["wear"]),
        ("updated", "robot1/0/23", 25, ["wear", "kl_raw", "kl_weighted"])]
    stats = agents[0].run_statistics()
    assert stats["faults"] == 1 and stats["alarms_chattering"] == 0
    assert [(a["quantity"], a["cycle"], a["fault"]) for a in stats["alarms"]] == [
        ("wear", 23, "robot1/0/23"), ("kl_raw", 25, "robot1/0/23"), ("kl_weighted", 25, "robot1/0/23")]
    jsonschema.validate(json.loads(json.dumps(stats)), load_schema("summary"))
    assert healthy.alarms == [] and agents[1].run_statistics()["faults"] == 0         # the other side


@pytest.mark.parametrize("chatter_cycles, state", [(20, "chattering"), (1, "raised")])
def test_a_crossing_soon_after_an_acknowledgement_is_chattering_and_after_the_window_a_new_fault(chatter_cycles, state):
    sink = Sink()
    agent = Agent(config(chatter_cycles), sinks=[sink])
    feed(agent, cycles(0, 27, 2.0))                        # cycle 26 stays open: 25 is the last published
    [raised] = [r for r in sink.alarms if r["state"] == "raised"]
    acknowledged = agent.acknowledge(0, by="alice")
    assert [a.fault for a in acknowledged.alarms] == [raised["fault"]] and acknowledged.alarms[0].open is False
    feed(agent, cycles(27, 8, 2.0))
    [after] = [r for r in sink.alarms if r["cycle"] > 25]                  # the ramp goes on: they cross again
    assert after["state"] == state and after["cycle"] - 25 > 1            # two cycles or more after the acknowledgement
    stats = agent.run_statistics()
    if state == "chattering":
        assert after["fault"] == raised["fault"] and after["open"] is True
        assert stats["faults"] == 1 and stats["alarms_chattering"] == 1
        assert agent.health().counters["alarms_chattering"] == 1
        assert agent.joints[0].faults.chattering == 1
    else:
        assert after["fault"] == f"robot1/0/{after['cycle']}" != raised["fault"]
        assert stats["faults"] == 2 and stats["alarms_chattering"] == 0


@pytest.mark.parametrize("keep_fault", [True, False])
def test_a_restart_from_the_state_file_keeps_the_open_fault(tmp_path, keep_fault):
    sink = Sink()
    agent = Agent(config(), sinks=[sink], state_store=StateStore(tmp_path))
    feed(agent, cycles(0, 26, 1.0))                      # raised at cycle 23, 25 is still open
    agent.close()
    assert summary(sink.alarms) == [("raised", "robot1/0/23", 23, ["wear"])]
    if not keep_fault:                                   # the other side: a state without the open fault
        store = StateStore(tmp_path)
        state = store.load()
        del state["joints"]["0"]["faults"]
        store.save(state)
    restarted = Agent(config(), sinks=[sink], state_store=StateStore(tmp_path))
    feed(restarted, cycles(26, 8, 1.0))
    later = [(r["state"], r["fault"]) for r in sink.alarms[1:]]
    assert later, "the ramp goes on: more detectors cross"
    if keep_fault:
        assert {state for state, _ in later} == {"updated"} and {f for _, f in later} == {"robot1/0/23"}
        assert restarted.run_statistics()["faults"] == 0            # nothing new raised after the restart
    else:
        assert later[0][0] == "raised" and later[0][1] != "robot1/0/23"


def test_advisories_are_published_and_counted_apart_from_alarms():
    """A motor temperature step after learning (an operating condition: the synthetic torque does not
    depend on it, the temperature compensation does): an advisory, counted as such, never as an alarm; the
    same wear ramp is one fault with or without the step."""
    stepped, steady = Sink(), Sink()
    agents = Agent(config(), sinks=[stepped]), Agent(config(), sinks=[steady])
    for agent, temperature in zip(agents, (60.0, 45.0)):
        feed(agent, cycles(0, ONSET + 16, 1.0, temperature=temperature))
    with_step, without = (agent.run_statistics() for agent in agents)
    assert [(a["state"], a["covariate"]) for a in stepped.advisories] == [("entered", "motor_temperature")]
    assert with_step["advisories"] == 1 and steady.advisories == [] and without["advisories"] == 0
    assert all("advisory" not in r and r["state"] in ("raised", "updated") for r in stepped.alarms)
    assert with_step["faults"] == without["faults"] == sum(r["state"] == "raised" for r in stepped.alarms)
    crossings = sum(1 for r in stepped.alarms for d in r["detectors"] if d["cycle"] == r["cycle"])
    assert len(with_step["alarms"]) == crossings                 # detector crossings only, no advisory among them
    assert agents[0].health().counters["alarms"] == len(with_step["alarms"])
