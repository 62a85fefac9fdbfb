"""What a consumer gets: `edge-monitor listen` as JSON lines filtered by robot/joint/kind (also kinds added
later), the state queryable for every joint the agent knows before its first cycle, alarm events in the
JSONL file, and real records valid against the JSON Schemas shipped in the package (`jsonschema`)."""

from __future__ import annotations

import json
import subprocess
import sys
from contextlib import ExitStack
from pathlib import Path

import jsonschema
import pytest
import zenoh.ext as zext
from test_agent_pipeline import SPEEDS, feed, small_config

from edge_monitor.app import Outputs, build_app
from edge_monitor.pipeline.agent import Agent
from edge_monitor.records import to_json
from edge_monitor.schemas import KINDS, load_schema
from edge_monitor.sinks.loopback import free_loopback_port
from edge_monitor.sinks.zenoh_publisher import SymptomPublisher
from edge_monitor.sinks.zenoh_session import ZenohOptions, open_session

from synthetic_frames import make_frames
from waiting import wait_until

EDGE = str(Path(sys.executable).parent / "edge-monitor")
WAIT_S = 30.0       # an upper bound for deliveries on a loaded machine, never a speed assertion
START_TIME = 1_795_000_000.0


def validate(kind: str, record: dict) -> None:
    jsonschema.validate(json.loads(to_json(record)), load_schema(kind),
                        format_checker=jsonschema.Draft202012Validator.FORMAT_CHECKER)


@pytest.fixture(scope="module")
def alarm_run(tmp_path_factory):
    """A synthetic run whose joint 0 wears at cycle 5 (an alarm), through the app with a JSONL output."""
    out = tmp_path_factory.mktemp("alarm")
    frames = make_frames(14, joints=(0,), speeds=SPEEDS, wear=lambda j, c: 0.0 if c < 5 else 60.0, seed=9,
                         start_time=START_TIME)
    config = small_config()
    with ExitStack() as stack:
        app = build_app(config, Outputs(jsonl=str(out / "s.jsonl")), stack)
        symptoms = feed(app.agent, frames) + app.agent.finish()
        cleared = app.agent.declare_maintenance(0)
        health = app.agent.health().to_dict()
        stats = app.agent.run_statistics()
    lines = [json.loads(x) for x in (out / "s.jsonl").read_text().splitlines()]
    return {"symptoms": symptoms, "cleared": cleared, "health": health, "stats": stats, "lines": lines}


def test_every_schema_is_a_valid_json_schema():
    for kind in KINDS:
        jsonschema.Draft202012Validator.check_schema(load_schema(kind))


def test_the_jsonl_file_holds_the_alarm_events_between_the_symptoms(alarm_run):
    lines = alarm_run["lines"]
    alarms = [r for r in lines if r.get("kind") == "alarm"]
    raised = [a for a in alarms if a["state"] == "raised"]
    # one record per fault: the run statistics count the faults and list every detector crossing in them
    assert raised and len(raised) == alarm_run["stats"]["faults"] == len({a["fault"] for a in alarms})
    crossings = [(a["joint"], d["cycle"], d["quantity"], a["fault"]) for a in alarms
                 if a["state"] in ("raised", "updated") for d in a["detectors"] if d["cycle"] == a["cycle"]]
    assert crossings == [(a["joint"], a["cycle"], a["quantity"], a["fault"]) for a in alarm_run["stats"]["alarms"]]
    cleared = [d["quantity"] for a in alarms if a["state"] == "cleared" for d in a["detectors"]]
    assert sorted(cleared) == sorted(c[2] for c in crossings)         # the maintenance clears every one of them
    symptoms = [r for r in lines if "kind" not in r]
    assert [r["cycle"] for r in symptoms] == list(range(14))
    first = lines.index(raised[0])          # written right after the symptom of the cycle that raised it
    assert lines[first - 1].get("cycle") == raised[0]["cycle"] and "kind" not in lines[first - 1]
    assert raised[0]["utc"] == lines[first - 1]["utc"] is not None


def test_real_records_are_valid_against_the_shipped_schemas(alarm_run):
    for symptom in alarm_run["symptoms"]:
        validate("symptom", symptom.to_dict())
        validate("friction", symptom.friction_record())
        for alarm in symptom.alarms:
            validate("alarm", alarm.to_dict())
    for line in alarm_run["lines"]:
        validate(line.get("kind", "symptom"), line)
    for alarm in alarm_run["cleared"]:
        validate("alarm", alarm.to_dict())
    validate("health", alarm_run["health"])
    validate("summary", alarm_run["stats"])
    with pytest.raises(jsonschema.ValidationError):           # the schemas do reject: a symptom is no alarm
        validate("alarm", alarm_run["symptoms"][0].to_dict())


def test_the_state_queryable_answers_for_every_known_joint_before_its_first_cycle(tmp_path):
    port = free_loopback_port()
    endpoint = f"tcp/127.0.0.1:{port}"
    config = small_config(joints=(0, 1, 3))
    frames = make_frames(1, joints=(0, 1), speeds=SPEEDS, seed=2)
    half = len(frames[0]) // 2
    with ExitStack() as stack:
        app = build_app(config, Outputs(zenoh=ZenohOptions(listen=[endpoint])), stack)
        feed(app.agent, frames, stop=half)        # inside the first cycle: no symptom yet
        assert app.agent.stats.symptoms == 0
        client = open_session(ZenohOptions(connect=[endpoint]))
        stack.callback(client.close)

        def replies() -> dict:
            return {str(r.ok.key_expr): json.loads(r.ok.payload.to_string())
                    for r in client.get("edge/robot1/*/state", timeout=5.0) if r.ok is not None}
        assert wait_until(lambda: len(replies()) == 3, WAIT_S)
        got = replies()
        assert sorted(got) == [f"edge/robot1/{j}/state" for j in (0, 1, 3)]
        assert got["edge/robot1/0/state"]["known"] is True and got["edge/robot1/3/state"]["known"] is False
        for reply in got.values():
            validate("state", reply)


def _listen(endpoint: str, *args: str) -> subprocess.Popen:
    return subprocess.Popen([EDGE, "listen", "--zenoh-connect", endpoint, *args], stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True)


def test_listen_prints_json_lines_filtered_by_robot_joint_and_kind_also_kinds_added_later():
    port = free_loopback_port()
    endpoint = f"tcp/127.0.0.1:{port}"
    session = open_session(ZenohOptions(listen=[endpoint]))
    symptoms = [s.to_dict() for s in _short_run()]
    listeners: list[subprocess.Popen] = []
    try:
        with SymptomPublisher(session, "cell7", joints=[0, 1], cache_size=64) as publisher:
            for record in symptoms:
                publisher.publish_symptom({**record, "robot": "cell7"})
            publisher.publish_health({"frames_total": 1})
            # a kind this version does not know, cached like symptoms so that the listeners' history finds it
            advisory = zext.declare_advanced_publisher(session, "edge/cell7/1/advisory",
                                                       cache=zext.CacheConfig(max_samples=4), publisher_detection=True,
                                                       sample_miss_detection=zext.MissDetectionConfig(heartbeat=0.5))
            advisory.put(json.dumps({"robot": "cell7", "joint": 1, "text": "grease soon"}))
            everything = _listen(endpoint, "--robot", "cell7", "--count", str(len(symptoms) + 1), "--kind",
                                 "symptom", "--kind", "advisory")
            joint1 = _listen(endpoint, "--joint", "1", "--kind", "symptom", "--count", "2")
            listeners += [everything, joint1]
            out, err = everything.communicate(timeout=60)
            out1, err1 = joint1.communicate(timeout=60)
    finally:
        for proc in listeners:
            if proc.poll() is None:   # a listener that did not finish must not outlive the test
                proc.kill()
                proc.communicate()
        session.close()
    assert everything.returncode == 0 and joint1.returncode == 0, err + err1
    lines = [json.loads(x) for x in out.splitlines()]
    assert [r["kind"] for r in lines].count("symptom") == len(symptoms)
    assert {"kind": "advisory", "key": "edge/cell7/1/advisory", "robot": "cell7", "joint": 1,
            "text": "grease soon"} in lines
    assert all(r["kind"] != "health" for r in lines)
    for r in lines:             # a line as listen prints it, "kind" and "key" in front, is valid (issue 50)
        if r["kind"] == "symptom":
            validate("symptom", r)
    with pytest.raises(jsonschema.ValidationError):        # ... and stays no alarm
        validate("symptom", {**lines[0], "kind": "alarm"})
    picked = [json.loads(x) for x in out1.splitlines()]
    assert [(r["kind"], r["joint"]) for r in picked] == [("symptom", 1), ("symptom", 1)]


def _short_run() -> list:
    agent = Agent(small_config())
    frames = make_frames(2, joints=(0, 1), speeds=SPEEDS, seed=4, start_time=START_TIME)
    return feed(agent, frames) + agent.finish()
