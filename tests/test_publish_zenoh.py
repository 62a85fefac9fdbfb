"""Zenoh publication across real sessions on loopback (multicast off, explicit endpoints, free ports)."""

from __future__ import annotations

import argparse
import json
import logging
import math
import signal
import socket
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import zenoh

from edge_monitor.commands.common import add_zenoh_arguments, zenoh_options
from edge_monitor.records import to_json
from edge_monitor.sinks.keys import KeyParts, parse_key
from edge_monitor.sinks.loopback import free_loopback_port as free_port
from edge_monitor.sinks.zenoh_publisher import SymptomPublisher, SymptomSubscriber
from edge_monitor.sinks.zenoh_session import ZenohOptions, ZenohSetupError, open_session

from waiting import wait_until

REPO = Path(__file__).resolve().parents[1]
WAIT_S = 20.0   # generous upper bound for deliveries on a loaded 2-core machine; never a speed assertion

pytestmark = pytest.mark.timeout(60)


def symptom(robot: str, joint: int, cycle: int) -> dict:
    """A complete schema-1 symptom record with values derived from the cycle number."""
    return {"schema": 1, "robot": robot, "joint": joint, "cycle": cycle, "t": 30.0 * cycle,
            "friction": {"speeds": [2.1, 41.7, 133.5], "torque": [0.05, 0.035, 0.05 + 1e-5 * cycle],
                         "stderr": [1e-3, 1e-3, 1e-3]},
            "wear": {"estimate": 0.1 * cycle, "std": 1.5, "temperature": 40.0 + cycle % 7},
            "kl": {"raw": 0.01 * cycle, "weighted": None},
            "decisions": {"wear": {"state": "monitoring", "statistic": float(cycle), "threshold": 12.5,
                                   "alarm": cycle > 12, "change_cycle": None, "delta": None,
                                   "miss_probability": 0.25}},
            "alarm": cycle > 12}


@pytest.fixture
def peers():
    """(publisher session listening on a free loopback port, subscriber session connected to it)."""
    port = free_port()
    endpoint = f"tcp/127.0.0.1:{port}"
    pub_session = open_session(ZenohOptions(listen=[endpoint]))
    sub_session = open_session(ZenohOptions(connect=[endpoint]))
    yield pub_session, sub_session
    sub_session.close()
    pub_session.close()


def test_every_symptom_arrives_in_order_and_complete(peers):
    pub_session, sub_session = peers
    n = 200
    with SymptomSubscriber(sub_session, "edge/**") as subscriber, \
            SymptomPublisher(pub_session, "r1", joints=[0], cache_size=n) as publisher:
        # Before the route exists, puts go nowhere and a burst's head can be lost for good (a race of
        # Zenoh's late-publisher history); the test is about a connected subscriber.
        assert wait_until(publisher.has_subscriber, WAIT_S)
        sent = [symptom("r1", 0, cycle) for cycle in range(n)]
        for record in sent:
            assert publisher.publish_symptom(record)
        assert subscriber.wait_for(lambda s: s.count("symptom") >= n, WAIT_S)
        got = subscriber.records("symptom")
        assert got == sent  # in order, every field intact (JSON round trip of the whole record)
        assert publisher.stats()["symptoms_published"] == n
        assert publisher.stats()["symptoms_undelivered"] == 0
        assert subscriber.misses == 0


def test_late_subscriber_recovers_cached_symptoms(peers):
    pub_session, sub_session = peers
    cache, n = 20, 50
    with SymptomPublisher(pub_session, "r1", joints=[1], cache_size=cache) as publisher:
        for cycle in range(n):
            publisher.publish_symptom(symptom("r1", 1, cycle))
        with SymptomSubscriber(sub_session, "edge/r1/**") as subscriber:
            assert subscriber.wait_for(lambda s: s.count("symptom") >= cache, WAIT_S)
            # the cache holds exactly the last `cache` records; nothing older can come back
            assert [r["cycle"] for r in subscriber.records("symptom")] == list(range(n - cache, n))
            publisher.publish_symptom(symptom("r1", 1, n))   # and live records follow the history
            assert subscriber.wait_for(lambda s: s.count("symptom") == cache + 1, WAIT_S)
            assert subscriber.records("symptom")[-1]["cycle"] == n


def test_republished_records_keep_the_last_cache_size_per_joint_and_reach_a_subscriber(peers):
    pub_session, sub_session = peers
    sub = SymptomSubscriber(sub_session, "edge/r1/**", history=True)
    publisher = SymptomPublisher(pub_session, "r1", [0, 1], cache_size=3)
    old = [symptom("r1", j, c) for c in range(5) for j in (0, 1)]      # an earlier run's JSONL tail
    assert publisher.republish_symptoms(old) == 6
    assert publisher.stats()["symptoms_republished"] == 6 and publisher.stats()["symptoms_published"] == 0
    wanted = {(j, c) for j in (0, 1) for c in (2, 3, 4)}
    assert wait_until(lambda: {(r["joint"], r["cycle"]) for r in sub.records("symptom")} >= wanted, WAIT_S)
    assert {(r["joint"], r["cycle"]) for r in sub.records("symptom")} == wanted
    publisher.close()
    sub.close()


def test_liveliness_token_appears_and_goes(peers):
    pub_session, sub_session = peers
    with SymptomSubscriber(sub_session) as subscriber:
        publisher = SymptomPublisher(pub_session, "robot-7", joints=[0])
        assert subscriber.wait_for(lambda s: "robot-7" in s.agents, WAIT_S)
        publisher.close()
        assert subscriber.wait_for(lambda s: "robot-7" not in s.agents, WAIT_S)


def test_queryable_answers_with_provided_state(peers):
    pub_session, sub_session = peers

    def state_of(joint: int) -> dict:
        return {"joint": joint, "detectors": {"wear": {"mean": 1.5 * joint, "nan": math.nan}}}

    with SymptomPublisher(pub_session, "r1", joints=[0, 2, 5], state_provider=state_of) as publisher:
        # the queryable is declared on the publisher side; retry until the route reaches the subscriber side
        assert wait_until(lambda: _query(sub_session, "edge/r1/2/state"), WAIT_S)
        replies = _query(sub_session, "edge/r1/2/state")
        assert replies == {"edge/r1/2/state": {"joint": 2, "detectors": {"wear": {"mean": 3.0, "nan": None}}}}
        everything = _query(sub_session, "edge/r1/*/state")
        assert sorted(everything) == [f"edge/r1/{j}/state" for j in (0, 2, 5)]
        # a joint not monitored, asked by name: an error reply naming the joints that are
        [unknown] = list(sub_session.get("edge/r1/3/state", timeout=5.0))
        assert unknown.ok is None and json.loads(unknown.err.payload.to_string()) == {
            "error": "robot r1 does not monitor joint 3 (it monitors joint(s) 0, 2, 5)", "unknown_joint": 3,
            "joints": [0, 2, 5]}
        assert publisher.queries_answered >= 3


def _query(session: zenoh.Session, selector: str) -> dict:
    out = {}
    for reply in session.get(selector, timeout=5.0):
        assert reply.ok is not None, reply.err.payload.to_string()
        out[str(reply.ok.key_expr)] = json.loads(reply.ok.payload.to_string())
    return out


def _route_ready(pub_session: zenoh.Session, sub_session: zenoh.Session) -> bool:
    """Wait until a put on ``pub_session`` reaches ``sub_session`` through the router. Until the router
    has the subscriber's declaration it drops what it cannot route (a CI run once lost all 20 symptoms
    that way on a loaded machine); declarations travel in order, so a probe subscriber declared after
    the symptom subscriber answers for it too."""
    arrived: list[int] = []
    probe = sub_session.declare_subscriber("probe/route", lambda _sample: arrived.append(1))
    try:
        return wait_until(lambda: pub_session.put("probe/route", b"?") or bool(arrived), WAIT_S)
    finally:
        probe.undeclare()


def test_client_mode_through_router_subprocess():
    port = free_port()
    router = _start_router(port)
    try:
        client = ZenohOptions(mode="client", connect=[f"tcp/127.0.0.1:{port}"])
        pub_session, sub_session = open_session(client), open_session(client)
        try:
            with SymptomSubscriber(sub_session) as subscriber, \
                    SymptomPublisher(pub_session, "fleet-a", joints=[0, 1]) as publisher:
                assert _route_ready(pub_session, sub_session)
                for cycle in range(10):
                    for joint in (0, 1):
                        publisher.publish_symptom(symptom("fleet-a", joint, cycle))
                assert subscriber.wait_for(lambda s: s.count("symptom") >= 20, WAIT_S)
                for joint in (0, 1):
                    cycles = [r["cycle"] for r in subscriber.records("symptom") if r["joint"] == joint]
                    assert cycles == list(range(10))
                assert subscriber.wait_for(lambda s: "fleet-a" in s.agents, WAIT_S)
        finally:
            pub_session.close()
            sub_session.close()
    finally:
        _stop_router(router)


def _start_router(port: int) -> subprocess.Popen:
    router = subprocess.Popen([str(Path(sys.executable).parent / "edge-monitor"), "router", "--port", str(port)],
                              stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    assert router.stdout.readline().strip() == f"zenoh router listening on tcp/127.0.0.1:{port}"
    return router


def _stop_router(router: subprocess.Popen) -> None:
    router.send_signal(signal.SIGTERM)
    router.communicate(timeout=20)
    assert router.returncode == 0


def test_disconnected_subscriber_recovers_cache_and_counts_the_rest():
    """Router restart between publisher and subscriber: the last `cache` records come back, the others
    are reported missed: exactly, since sequence numbers make the gap known."""
    port, cache, before, during = free_port(), 5, 3, 20
    router = _start_router(port)
    client = ZenohOptions(mode="client", connect=[f"tcp/127.0.0.1:{port}"])
    pub_session, sub_session = open_session(client), open_session(client)
    try:
        with SymptomSubscriber(sub_session) as subscriber, \
                SymptomPublisher(pub_session, "r1", joints=[0], cache_size=cache) as publisher:
            for cycle in range(before):
                publisher.publish_symptom(symptom("r1", 0, cycle))
            assert subscriber.wait_for(lambda s: s.count("symptom") == before, WAIT_S)
            _stop_router(router)
            for cycle in range(before, before + during):      # nobody can receive these now
                publisher.publish_symptom(symptom("r1", 0, cycle))
            router = _start_router(port)                      # the clients reconnect by themselves
            expected = list(range(before)) + list(range(before + during - cache, before + during))
            assert subscriber.wait_for(lambda s: s.count("symptom") == len(expected), WAIT_S)
            assert [r["cycle"] for r in subscriber.records("symptom")] == expected
            assert subscriber.wait_for(lambda s: s.misses == during - cache, WAIT_S)
    finally:
        pub_session.close()
        sub_session.close()
        _stop_router(router)


def test_friction_and_health_telemetry_arrive(peers):
    """DROP telemetry: once the subscription has reached the publisher, puts arrive intact."""
    pub_session, sub_session = peers
    friction = {"schema": 1, "robot": "r1", "joint": 4, "cycle": 17, "speeds": [2.1, 41.7],
                "torque": [0.05, math.nan], "stderr": [1e-3, 2e-3]}
    with SymptomSubscriber(sub_session, history=False) as subscriber, \
            SymptomPublisher(pub_session, "r1", joints=[4]) as publisher:
        def delivered(s: SymptomSubscriber) -> bool:
            if not (s.count("friction") and s.count("health")):
                publisher.publish_friction(friction)
                publisher.publish_health({"frames_total": 1200, "queue_depth": 0})
            return bool(s.count("friction") and s.count("health"))

        assert wait_until(lambda: delivered(subscriber), WAIT_S)
        assert subscriber.records("friction")[0] == {"schema": 1, "robot": "r1", "joint": 4, "cycle": 17,
                                                     "speeds": [2.1, 41.7], "torque": [0.05, None],
                                                     "stderr": [1e-3, 2e-3]}
        health = subscriber.records("health")[0]
        assert health["frames_total"] == 1200 and health["robot"] == "r1"
        assert health["symptoms_published"] == 0 and health["symptoms_undelivered"] == 0
        key = subscriber.received()[0].key
        assert key in ("edge/r1/4/friction", "edge/r1/agent/health")


def test_unreachable_router_gives_clear_error():
    with pytest.raises(ZenohSetupError, match="no Zenoh router reachable"):
        open_session(ZenohOptions(mode="client", connect=[f"tcp/127.0.0.1:{free_port()}"]))


def test_occupied_port_gives_clear_error():
    with socket.socket() as holder:
        holder.bind(("127.0.0.1", 0))
        holder.listen()
        port = holder.getsockname()[1]
        with pytest.raises(ZenohSetupError, match="in use"):
            open_session(ZenohOptions(listen=[f"tcp/127.0.0.1:{port}"]))


def test_publishing_failures_are_counted_not_raised(caplog):
    session = open_session(ZenohOptions())   # peer, nothing to talk to: puts go nowhere, without error
    try:
        publisher = SymptomPublisher(session, "r1", joints=[0])
        assert publisher.publish_symptom(symptom("r1", 0, 0))
        with caplog.at_level(logging.WARNING):
            assert not publisher.publish_symptom({"joint": "not-a-joint"})
            publisher.close()
            for cycle in range(3):
                assert not publisher.publish_symptom(symptom("r1", 0, cycle))
            assert not publisher.publish_health({"frames_total": 1})
        stats = publisher.stats()
        assert (stats["symptoms_published"], stats["symptoms_undelivered"]) == (1, 4)
        assert stats["health_undelivered"] == 1
        # logged once per kind, then only counted
        assert sum("symptom not delivered" in r.message for r in caplog.records) == 1
        assert sum("health not delivered" in r.message for r in caplog.records) == 1
    finally:
        session.close()


def test_to_json_is_strict():
    record = {"a": math.nan, "b": [1.0, math.inf, -math.inf], "c": np.float32(0.5), "d": np.arange(3),
              "e": np.bool_(True), "f": {"g": np.int64(7)}}
    text = to_json(record)
    assert json.loads(text) == {"a": None, "b": [1.0, None, None], "c": 0.5, "d": [0, 1, 2], "e": True,
                                "f": {"g": 7}}
    assert "NaN" not in text and "Infinity" not in text


def test_parse_key():
    assert parse_key("edge/r1/3/symptom") == KeyParts("r1", 3, "symptom")
    assert parse_key("edge/r1/agent/health") == KeyParts("r1", None, "health")
    for bad in ("edge/r1/x/symptom", "other/r1/3/symptom", "edge/r*/3/symptom", "edge/r1/3", "edge/r1/3/symptom/x",
                "edge/r1/-1/maintenance", "edge/r1/12345/maintenance", "edge/r1/3/"):
        assert parse_key(bad) is None, bad


def test_default_options_stay_private():
    parser = argparse.ArgumentParser()
    add_zenoh_arguments(parser)
    options = zenoh_options(parser.parse_args([]))
    assert (options.mode, options.listen, options.connect) == ("peer", [], [])
    config = options.to_config()
    assert json.loads(config.get_json("scouting/multicast/enabled")) is False
    assert json.loads(config.get_json("listen/endpoints")) == []
    options = zenoh_options(parser.parse_args(
        ["--zenoh-mode", "client", "--zenoh-connect", "tcp/127.0.0.1:7447"]))
    assert json.loads(options.to_config().get_json("connect/endpoints")) == ["tcp/127.0.0.1:7447"]


def test_bad_options_name_the_flag(tmp_path):
    with pytest.raises(ZenohSetupError, match="--zenoh-connect"):
        ZenohOptions(connect=["127.0.0.1:7447"])
    with pytest.raises(ZenohSetupError, match="--zenoh-mode"):
        ZenohOptions(mode="server")
    with pytest.raises(ZenohSetupError, match="does not exist; fix --zenoh-config"):
        ZenohOptions(config_file=str(tmp_path / "missing.json5"))
    with pytest.raises(ZenohSetupError, match="is not a file; fix --zenoh-config"):
        ZenohOptions(config_file=str(tmp_path))                       # a folder given for the file
    bad = tmp_path / "bad.json5"
    bad.write_text("{ not_a_zenoh_key: 1 }")
    with pytest.raises(ZenohSetupError, match="invalid"):
        ZenohOptions(config_file=str(bad)).to_config()


def test_config_file_with_multicast_warns(tmp_path, caplog):
    loud = tmp_path / "loud.json5"
    loud.write_text('{ mode: "peer", scouting: { multicast: { enabled: true } }, listen: { endpoints: [] } }')
    with caplog.at_level(logging.WARNING):
        config = ZenohOptions(mode=None, config_file=str(loud)).to_config()
    assert any("multicast scouting on" in r.message for r in caplog.records)
    assert json.loads(config.get_json("mode")) == "peer"
    quiet = tmp_path / "quiet.json5"
    quiet.write_text('{ scouting: { multicast: { enabled: false } } }')
    caplog.clear()
    with caplog.at_level(logging.WARNING):
        ZenohOptions(mode=None, config_file=str(quiet)).to_config()
    assert not any("multicast" in r.message for r in caplog.records)


def test_has_subscriber_follows_a_subscriber_coming_and_going(peers):
    pub_session, sub_session = peers
    with SymptomPublisher(pub_session, "r1", joints=[0]) as publisher:
        assert not publisher.has_subscriber()
        with SymptomSubscriber(sub_session, "edge/r1/**"):
            assert wait_until(publisher.has_subscriber, WAIT_S)
        assert wait_until(lambda: not publisher.has_subscriber(), WAIT_S)
        with SymptomSubscriber(sub_session, "edge/other-robot/**"):
            assert not wait_until(publisher.has_subscriber, 1.0)   # another robot's keys do not count
