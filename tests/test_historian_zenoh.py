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
