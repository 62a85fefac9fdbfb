"""The historian over real Zenoh (a router session on loopback, multicast off): records of agents'
publishers stored exactly once, a historian that was down catching up from the publishers' caches, the
queryable's answers and its clear refusals, and hostile puts counted, never stored."""

from __future__ import annotations

import json

import pytest
from historian_support import symptom

from edge_monitor.historian.client import HistoryRefused, zenoh_asker
from edge_monitor.historian.database import connect
from edge_monitor.historian.db_url import parse_db
from edge_monitor.historian.query_spec import HistoryQuery
from edge_monitor.historian.service import Historian
from edge_monitor.sinks.loopback import free_loopback_port
from edge_monitor.sinks.zenoh_publisher import SymptomPublisher
from edge_monitor.sinks.zenoh_session import ZenohOptions, open_session

from waiting import wait_until

WAIT_S = 30.0        # an upper bound for deliveries on a loaded machine, never a speed assertion


@pytest.fixture
def router():
    endpoint = f"tcp/127.0.0.1:{free_loopback_port()}"
    session = open_session(ZenohOptions(mode="router", listen=[endpoint]))
    yield endpoint
    session.close()


def client(endpoint):
    return open_session(ZenohOptions(mode="client", connect=[endpoint]))


def stored(target, kind="symptom"):
    conn = connect(target)
    try:
        return conn.rows("SELECT COUNT(*) FROM records WHERE kind = ?", (kind,))[0][0]
    finally:
        conn.close()


def publish(publisher, robot, cycles):
    for cycle in cycles:
        for joint in (0, 1):
            record = symptom(robot, joint, cycle)
            publisher.publish_symptom(record)
            publisher.publish_friction({"schema": 1, "robot": robot, "joint": joint, "cycle": cycle,
                                        "utc": record["utc"], **record["friction"]})


def start_historian(endpoint, target):
    session = client(endpoint)
    return session, Historian(session, target).start()


def test_a_historian_stores_live_records_and_catches_up_after_it_was_down(router, tmp_path):
    target = parse_db(str(tmp_path / "plant.db"))
    agent = client(router)
    publisher = SymptomPublisher(agent, "r1", (0, 1))
    session, historian = start_historian(router, target)
    assert wait_until(publisher.has_subscriber, WAIT_S)
    publish(publisher, "r1", range(10))
    assert wait_until(lambda: stored(target) == 20, WAIT_S)
    historian.close()
    session.close()
    publish(publisher, "r1", range(10, 25))            # while the historian is down
    session, historian = start_historian(router, target)
    try:
        # the advanced subscriber asks the publishers' caches (256 per key): cycles 0 … 24 come again
        assert wait_until(lambda: stored(target) == 50, WAIT_S), stored(target)
        assert wait_until(lambda: historian.status()["duplicates"] >= 20, WAIT_S)
        assert stored(target, "friction") == 50                  # the curves of the missed cycles, from symptoms
        ask = zenoh_asker(client(router))
        gaps = ask(HistoryQuery(what="gaps"))
        assert gaps["gaps"] == [] and gaps["count"] == 0
    finally:
        historian.close()
        session.close()
        publisher.close()
        agent.close()


def test_the_queryable_answers_and_refuses_clearly(router, tmp_path):
    target = parse_db(str(tmp_path / "plant.db"))
    session, historian = start_historian(router, target)
    agent = client(router)
    reader = client(router)
    publisher = SymptomPublisher(agent, "cell7", (0, 1))
    try:
        assert wait_until(publisher.has_subscriber, WAIT_S)
        publish(publisher, "cell7", range(5))
        assert wait_until(lambda: stored(target) == 10, WAIT_S)
        ask = zenoh_asker(reader)
        page = ask(HistoryQuery(robot="cell7", joint=1, kinds=("symptom",), limit=3))
        assert [r["cycle"] for r in page["records"]] == [0, 1, 2] and page["truncated"] and page["next"]
        everything = ask(HistoryQuery(since=0.0, until=2.5e11, limit=1000))       # a huge range: bounded
        assert everything["count"] == 20 and not everything["truncated"]
        nobody = ask(HistoryQuery(robot="cell8"))
        assert nobody["robot_known"] is False and "cell7" in nobody["message"]
        fleet = ask(HistoryQuery(what="fleet"))
        assert [j["online"] for j in fleet["joints"]] == [True, True]
        for selector, words in (("edge/history/records?limit=0", "limit"), ("edge/history/records?colour=red",
                                 "unknown parameter"), ("edge/history/records?since=yesterday", "ISO 8601"),
                                ("edge/history/records?robot=a%2Fb", "robot"), ("edge/history/**", "ask one question"),
                                ("edge/history/nonsense", "ask one question")):
            replies = list(reader.get(selector, timeout=10))
            assert len(replies) == 1 and replies[0].err is not None, selector
            assert words in json.loads(replies[0].err.payload.to_string())["error"], selector
        status = json.loads(list(reader.get("edge/history/status", timeout=10))[0].ok.payload.to_string())
        assert status["stored"] == 20 and status["agents_online"] == ["cell7"]
        with pytest.raises(HistoryRefused, match="daily summaries"):          # the client says what it was told
            ask(_UncheckedQuery(kinds=("daily",)))
    finally:
        publisher.close()
        historian.close()
        for s in (session, agent, reader):
            s.close()


class _UncheckedQuery(HistoryQuery):
    """A question that skips the local checks, to see the historian's own refusal."""

    def __post_init__(self) -> None:
        pass


def test_hostile_puts_are_counted_never_stored(router, tmp_path):
    target = parse_db(str(tmp_path / "plant.db"))
    session, historian = start_historian(router, target)
    forger = client(router)
    try:
        good = symptom("r1", 0, 3)
        puts = [("edge/r1/0/symptom", b"not json"), ("edge/r1/0/symptom", json.dumps({**good, "robot": "r2"})),
                ("edge/r1/1/symptom", json.dumps(good)), ("edge/r1/0/symptom", json.dumps([1, 2])),
                ("edge/r1/0/alarm", json.dumps({"robot": "r1", "joint": 0})), ("edge/r1/0/acknowledge", b"{}"),
                ("edge/r1/0/symptom", json.dumps(good))]
        for key, payload in puts:
            forger.put(key, payload)
        assert wait_until(lambda: stored(target) == 1, WAIT_S)
        assert wait_until(lambda: sum(historian.status()["rejected"].values()) == 3, WAIT_S), historian.status()
        assert historian.status()["zenoh_undecodable"] == 2 and historian.status()["ignored"] == 1
        assert stored(target, "alarm") == 0
    finally:
        historian.close()
        session.close()
        forger.close()


def test_a_robot_cannot_close_another_robots_fault_and_unusable_records_are_counted(router, tmp_path):
    """The attack pass's puts: r8 "clearing" r9's fault, records without their schema's fields, a wall time
    that is no time or in the year 9999, a string where a flag belongs, the reserved robot name "history";
    each refused and counted by reason, while r9's own alarm and symptom are stored."""
    from historian_support import alarm

    target = parse_db(str(tmp_path / "plant.db"))
    session, historian = start_historian(router, target)
    forger = client(router)
    try:
        good = symptom("r9", 0, 3)
        hijack = {**alarm("r8", 0, 99, "cleared", 99, open_=False), "fault": "r9/0/1"}
        puts = [("edge/r9/0/alarm", alarm("r9", 0, 1, "raised", 1)), ("edge/r8/0/alarm", hijack),
                ("edge/r9/0/symptom", {"cycle": 7}), ("edge/r9/0/symptom", {**good, "utc": "yesterday at noon"}),
                ("edge/r9/0/symptom", {**good, "utc": "9999-12-31T23:59:59.999Z"}),
                ("edge/r9/0/alarm", {**alarm("r9", 0, 2, "updated", 1), "open": "yes"}),
                ("edge/history/0/symptom", symptom("history", 0, 3)), ("edge/r9/0/symptom", good)]
        for key, record in puts:
            forger.put(key, json.dumps(record))
        assert wait_until(lambda: stored(target) == 1 and stored(target, "alarm") == 1, WAIT_S)
        assert wait_until(lambda: sum(historian.status()["rejected"].values()) == 6, WAIT_S), historian.status()
        assert historian.status()["rejected"] == {"fault_mismatch": 1, "missing_field": 1, "utc": 1, "utc_ahead": 1,
                                                  "bad_field": 1, "robot": 1}
        conn = connect(target)
        try:
            assert conn.rows("SELECT robot, state, is_open FROM faults") == [("r9", "raised", 1)]
        finally:
            conn.close()
    finally:
        historian.close()
        session.close()
        forger.close()


def test_historian_json_prints_only_the_status_on_stdout(router, tmp_path):
    import subprocess
    import sys
    from pathlib import Path

    done = subprocess.run([str(Path(sys.executable).parent / "edge-monitor"), "historian", "--db",
                           str(tmp_path / "plant.db"), "--zenoh-mode", "client", "--zenoh-connect", router,
                           "--duration", "1", "--json"], capture_output=True, text=True, timeout=120)
    assert done.returncode == 0, done.stderr
    status = json.loads(done.stdout)
    assert status["received"] == 0 and "historian ready: storing into" in done.stderr
