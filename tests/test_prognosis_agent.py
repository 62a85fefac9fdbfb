"""The prognosis in the agent (docs/PROGNOSIS.md): in every symptom and in the alarm record, valid against
the shipped schemas (also as `edge-monitor listen` prints them), reset by a maintenance, kept across a
restart, the same as the study's replay of the published series, with a per-joint critical wear and the
optional early warning."""

from __future__ import annotations

import dataclasses
import json
import subprocess
import sys
from pathlib import Path

import jsonschema
import pytest
from test_agent_pipeline import SPEEDS, feed, small_config

from edge_monitor.config import config_from_mapping
from edge_monitor.features.prognosis import JointPrognosis, PrognosisConfig
from edge_monitor.pipeline.agent import Agent
from edge_monitor.pipeline.state_store import StateStore
from edge_monitor.records import to_json
from edge_monitor.schemas import load_schema
from edge_monitor.sinks.loopback import free_loopback_port
from edge_monitor.sinks.zenoh_publisher import SymptomPublisher
from edge_monitor.sinks.zenoh_session import ZenohOptions, open_session

from recordings import rows_by_entity
from synthetic_frames import make_frames

EDGE = str(Path(sys.executable).parent / "edge-monitor")
CYCLES = 40


def wear(joint: int, cycle: int) -> float:
    """Joint 0 wears 2 per cycle from cycle 10 (critical 35 at cycle 27.5); joint 1 stays healthy."""
    return 0.0 if joint == 1 or cycle < 10 else 2.0 * (cycle - 10)


def config(**prognosis):
    return small_config(prognosis=PrognosisConfig(**{"learning_cycles": 5, **prognosis}))


@pytest.fixture(scope="module")
def frames():
    return make_frames(CYCLES, joints=(0, 1), speeds=SPEEDS, wear=wear, seed=21, start_time=1_795_000_000.0)


@pytest.fixture(scope="module")
def run(frames):
    agent = Agent(config())
    symptoms = feed(agent, frames) + agent.finish()
    return agent, symptoms


def validate(kind: str, record: dict) -> None:
    jsonschema.validate(json.loads(to_json(record)), load_schema(kind),
                        format_checker=jsonschema.Draft202012Validator.FORMAT_CHECKER)


def sections(symptoms, joint):
    return [s.to_dict()["prognosis"] for s in symptoms if s.joint == joint]


def test_the_wearing_joint_gets_a_forecast_with_its_alarm_and_the_healthy_one_none(run):
    agent, symptoms = run
    worn, healthy = sections(symptoms, 0), sections(symptoms, 1)
    assert worn[0]["state"] == healthy[0]["state"] == "learning"
    # the healthy joint forecasts nothing while none of its detectors is in alarm (this short synthetic
    # run's detectors, learned from 3 values at Pf 1e-3, may well raise a false one: then it forecasts)
    quiet = [s.to_dict()["prognosis"] for s in symptoms if s.joint == 1 and not s.alarm]
    assert len(quiet) > 5 and {p["state"] for p in quiet[5:]} == {"no_trend"} and all(p["beyond_horizon"] for p in quiet)
    records = [a for s in symptoms for a in s.alarms if a.joint == 0 and a.state in ("raised", "updated")]
    assert records and all(a.prognosis is not None for a in records)
    # every alarm record carries its cycle's prognosis. The fault's records may all come before the rate
    # stands out ("no growing wear found": here every detector alarms within 2 cycles); the joint's
    # symptoms then forecast with a band while the alarm is latched
    by_cycle = {s.cycle: s.to_dict()["prognosis"] for s in symptoms if s.joint == 0}
    assert all(a.prognosis == by_cycle[a.cycle] for a in records)
    forecasts = [p for s in symptoms if s.joint == 0 and s.alarm
                 for p in [s.to_dict()["prognosis"]] if p["state"] == "forecast"]
    assert forecasts, [a.prognosis["text"] for a in records]
    first = forecasts[0]
    band = first["cycles"]
    assert first["days"]["median"] > 0 and band["p10"] <= band["median"] <= (band["p90"] or float("inf"))
    assert "critical wear 35 in about" in first["text"]
    assert worn[-1]["state"] == "critical"
    for s in symptoms:
        validate("symptom", s.to_dict())
        for alarm in s.alarms:
            validate("alarm", alarm.to_dict())


def test_the_published_series_replayed_gives_the_published_prognosis(run):
    # the prognosis study's premise: the trend sees only what a symptom publishes (its wear input, std, the
    # joint's alarm state, partial), so replaying a joint's symptoms reproduces its prognosis exactly
    agent, symptoms = run
    records = [s.to_dict() for s in symptoms if s.joint == 0]
    prognosis = JointPrognosis(agent.config.prognosis, agent.config.critical_wear_for(0))
    wear_input = agent.config.prognosis.wear_input
    for r in records:
        forecast = prognosis.update(r["cycle"], r["wear"].get(wear_input), r["wear"]["std"], use=not r.get("partial"),
                                    alarm=r["alarm"], cycles_per_day=r["prognosis"]["cycles_per_day"])
        assert forecast.section() == r["prognosis"]


def test_the_posterior_mean_feeds_the_trend_when_configured(frames):
    # wear_input = "posterior_mean": the published posterior means replayed give the published prognosis,
    # and it differs from the default's (the two inputs differ on a wearing joint)
    agent = Agent(config(wear_input="posterior_mean"))
    records = [s.to_dict() for s in feed(agent, frames) + agent.finish() if s.joint == 0]
    by_mean, by_estimate = (JointPrognosis(agent.config.prognosis, agent.config.critical_wear_for(0)) for _ in "ab")
    changed = 0
    for r in records:
        fed = dict(use=not r.get("partial"), alarm=r["alarm"], cycles_per_day=r["prognosis"]["cycles_per_day"])
        assert by_mean.update(r["cycle"], r["wear"]["posterior_mean"], r["wear"]["std"], **fed).section() \
            == r["prognosis"]
        changed += by_estimate.update(r["cycle"], r["wear"]["estimate"], r["wear"]["std"], **fed).section() \
            != r["prognosis"]
    assert changed > 0


def test_a_maintenance_starts_the_trend_again(frames):
    agent = Agent(config())
    feed(agent, frames)
    assert agent.joints[0].prognosis.trend.updates > 20
    agent.declare_maintenance(0)
    assert agent.joints[0].prognosis.trend.updates == 0
    assert agent.joints[1].prognosis.trend.updates > 20          # the other joint keeps its history


def test_a_restart_keeps_the_trend(frames, tmp_path):
    half = len(frames[0]) // 2
    first = Agent(config(), state_store=StateStore(tmp_path))
    feed(first, frames, stop=half)
    first.close()
    saved = first.joints[0].prognosis.state_dict()
    assert saved["trend"]["filters"][0]["updates"] > 10
    # the state file holds the trend the agent had, exactly (JSON keeps floats exactly)
    state = json.loads(StateStore(tmp_path).path.read_text())
    assert state["joints"]["0"]["prognosis"] == json.loads(json.dumps(saved))
    second = Agent(config(), state_store=StateStore(tmp_path))
    resumed = feed(second, frames, start=half) + second.finish()
    restored = second.joints[0].prognosis
    assert restored.trend.updates > saved["trend"]["filters"][0]["updates"]     # went on, did not start again
    assert [s.to_dict()["prognosis"]["state"] for s in resumed if s.joint == 0][-1] == "critical"


def test_a_joint_has_its_own_critical_wear(frames):
    cfg = dataclasses.replace(config(), joint_critical_wear={0: 25.0})
    agent = Agent(cfg)
    symptoms = feed(agent, frames) + agent.finish()
    last = [s.to_dict() for s in symptoms if s.joint == 0][-1]
    assert last["critical_wear"] == last["prognosis"]["critical_wear"] == 25.0
    assert [s.to_dict() for s in symptoms if s.joint == 1][-1]["prognosis"]["critical_wear"] == 35.0
    assert config_from_mapping({"joint": {"0": {"critical_wear": 25}}}).critical_wear_for(0) == 25.0


def test_the_early_warning_is_an_advisory_with_the_forecast(frames):
    agent = Agent(config(warning_probability=0.5))
    symptoms = feed(agent, frames) + agent.finish()
    warnings = [a for s in symptoms for a in s.advisories if a.kind == "prognosis"]
    alarmed = {(s.joint, s.cycle) for s in symptoms if s.alarm}
    # a warning needs a forecast, which needs the joint's alarm (joint 1 may have a false one in this run)
    assert [w.state for w in warnings if w.joint == 0][:1] == ["entered"]
    assert all((w.joint, w.cycle) in alarmed for w in warnings if w.state == "entered")
    record = warnings[0].to_dict()
    validate("advisory", record)
    assert record["value"] >= 0.5 and record["covariate"] == "p_critical_7d" and record["prognosis"]["state"] in (
        "forecast", "critical")
    assert "plan the service" in record["message"]
    assert agent.stats.advisories >= 1


def test_listen_prints_forecasts_that_validate_against_the_schemas(run):
    _, symptoms = run
    port = free_loopback_port()
    endpoint = f"tcp/127.0.0.1:{port}"
    session = open_session(ZenohOptions(listen=[endpoint]))
    records = [s.to_dict() for s in symptoms if s.joint == 0]
    alarms = [a.to_dict() for s in symptoms for a in s.alarms if a.joint == 0]
    assert any("prognosis" in a for a in alarms)
    listener = None
    try:
        with SymptomPublisher(session, "robot1", joints=[0], cache_size=64) as publisher:
            for record in records:
                publisher.publish_symptom(record)
            for alarm in alarms:
                publisher.publish_alarm(alarm)
            listener = subprocess.Popen([EDGE, "listen", "--zenoh-connect", endpoint, "--kind", "symptom", "--kind",
                                         "alarm", "--count", str(len(records) + len(alarms)), "--duration", "60"],
                                        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
            out, err = listener.communicate(timeout=90)
    finally:
        if listener is not None and listener.poll() is None:    # a listener that did not finish must not outlive it
            listener.kill()
            listener.communicate()
        session.close()
    assert listener.returncode == 0, err
    lines = [json.loads(x) for x in out.splitlines()]
    assert {r["prognosis"]["state"] for r in lines if r["kind"] == "symptom"} >= {"learning", "forecast", "critical"}
    for r in lines:
        validate(r["kind"], {k: v for k, v in r.items() if k not in ("kind", "key")})


def test_rerun_draws_the_trend_the_days_and_the_forecast_cone(run, tmp_path):
    from rerun.chunk import RrdReader

    from edge_monitor.sinks.rerun_view import RerunSink

    _, symptoms = run
    path = tmp_path / "prognosis.rrd"
    sink = RerunSink.open(f"save:{path}", recording_id="prognosis")
    for s in symptoms:
        sink.log_symptom(s.to_dict())
    sink.close()
    assert sink.errors == 0
    counts = rows_by_entity(path)
    base = "/robot/robot1/joint/0"
    assert counts[f"{base}/wear/trend"] > 20 and counts[f"{base}/prognosis/days/median"] >= 1
    assert counts[f"{base}/prognosis/cone"] >= 1
    strips = [row for chunk in RrdReader(str(path)).stream() if chunk.entity_path == f"{base}/prognosis/cone"
              and not chunk.is_static for row in chunk.to_record_batch().column("LineStrips2D:strips").to_pylist()]
    # each cone holds the trend behind "now", the critical level (y = 35) and the horizon line
    assert strips and all(any(all(point[1] == 35.0 for point in strip) for strip in cone) for cone in strips)
