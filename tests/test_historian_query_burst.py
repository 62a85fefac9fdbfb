"""A burst of history questions over real Zenoh (peer sessions on loopback, multicast scouting off) never
holds the historian's Zenoh thread: while the database is kept busy, ``edge/history/status`` is still
answered and records are still received; at most ``MAX_WAITING`` questions wait, the others get a counted
"busy, retry" reply; every question gets exactly one reply, and the counters add up. The database work is
held by a gate the test opens, so the verdict never depends on the machine's speed."""

from __future__ import annotations

import json
import threading

import pytest
from historian_support import symptom

from edge_monitor.historian import zenoh_answers
from edge_monitor.historian.client import HistoryUnavailable, zenoh_asker
from edge_monitor.historian.db_url import parse_db
from edge_monitor.historian.query_spec import HistoryQuery
from edge_monitor.historian.service import Historian
from edge_monitor.sinks.loopback import free_loopback_port
from edge_monitor.sinks.zenoh_publisher import SymptomPublisher
from edge_monitor.sinks.zenoh_session import ZenohOptions, open_session

from waiting import wait_until

WAIT_S = 30.0          # an upper bound for deliveries on a loaded machine, never a speed assertion
BURST = 40
REPLY_S = 60.0         # the askers' Zenoh timeout: far beyond anything the test waits for


class GatedHistorian:
    """A historian on a peer session listening on loopback, whose database answers wait for ``gate``."""

    def __init__(self, tmp_path) -> None:
        self.endpoint = f"tcp/127.0.0.1:{free_loopback_port()}"
        self.session = open_session(ZenohOptions(mode="peer", listen=[self.endpoint]))
        self.historian = Historian(self.session, parse_db(str(tmp_path / "plant.db")))
        self.gate = threading.Event()
        self.started = 0
        answer = self.historian._answer

        def gated(ask):
            self.started += 1
            assert self.gate.wait(WAIT_S * 4), "the test never opened the gate"
            return answer(ask)

        self.historian._answer = gated          # type: ignore[method-assign]
        self.historian.start()
        self.closed: dict | None = None

    def peer(self):
        return open_session(ZenohOptions(mode="peer", connect=[self.endpoint]))

    def questions(self) -> dict:
        return self.historian.status()["questions"]

    def close(self) -> dict:
        if self.closed is None:
            self.gate.set()
            self.closed = self.historian.close()
            self.session.close()
        return self.closed


@pytest.fixture
def gated(tmp_path, monkeypatch):
    monkeypatch.setattr(zenoh_answers, "ANSWER_TIMEOUT_S", 300.0)     # the gate, not the time limit, decides
    served = GatedHistorian(tmp_path)
    yield served
    served.close()


def replies_of(handler) -> list:
    return list(handler)


def status_now(reader) -> dict:
    replies = list(reader.get("edge/history/status", timeout=WAIT_S))
    assert len(replies) == 1 and replies[0].ok is not None, "no status answer while questions wait"
    return json.loads(replies[0].ok.payload.to_string())


def test_a_burst_of_questions_never_holds_the_status_nor_the_records(gated):
    reader, agent = gated.peer(), gated.peer()
    publisher = SymptomPublisher(agent, "r1", (0,))
    try:
        assert wait_until(publisher.has_subscriber, WAIT_S)
        burst = [reader.get(f"edge/history/records?robot=r1;limit={n % 5 + 1}", timeout=REPLY_S) for n in range(BURST)]
        waiting = zenoh_answers.MAX_WAITING
        assert wait_until(lambda: gated.questions()["busy"] == BURST - waiting, WAIT_S), gated.questions()
        status = status_now(reader)                # answered while the database is held
        assert status["questions"]["waiting"] == waiting and status["questions"]["busy"] == BURST - waiting
        for cycle in range(3):                     # records keep arriving during the burst
            publisher.publish_symptom(symptom("r1", 0, cycle))
        assert wait_until(lambda: gated.historian.status()["received"] == 3, WAIT_S), {k: v for k, v in gated.historian.status().items() if k != "database"}
        with pytest.raises(HistoryUnavailable, match=r"the historian is busy: .* retry in a few seconds"):
            zenoh_asker(reader, timeout_s=WAIT_S)(HistoryQuery(robot="r1"))
        assert gated.started == 1                  # one question at the database, the others wait their turn
        gated.gate.set()
        answers, busy = [], []
        for handler in burst:
            replies = replies_of(handler)
            assert len(replies) == 1                # exactly one reply per question
            if replies[0].ok is not None:
                answers.append(json.loads(replies[0].ok.payload.to_string()))
            else:
                error = json.loads(replies[0].err.payload.to_string())
                assert error["busy"] is True and error["refused"] is False and "retry" in error["error"]
                busy.append(error)
        assert len(answers) == waiting and len(busy) == BURST - waiting
        assert all(a["answer"] == "records" for a in answers)
        counted = gated.questions()
        assert counted["busy"] == len(busy) + 1                       # and the asker's one
        assert counted["answered"] == len(answers) + 1 and counted["waiting"] == 0     # + one status answer
        assert counted["refused"] == 0
        assert wait_until(lambda: gated.historian.status().get("stored_symptom") == 3, WAIT_S), {k: v for k, v in gated.historian.status().items() if k != "database"}
    finally:
        publisher.close()
        reader.close()
        agent.close()


def test_questions_still_waiting_at_the_stop_are_told_so(gated):
    reader = gated.peer()
    try:
        pending = [reader.get("edge/history/fleet", timeout=REPLY_S) for _ in range(3)]
        assert wait_until(lambda: gated.questions()["waiting"] == 3, WAIT_S), gated.questions()
        pool, cancelled = gated.historian._pool, threading.Event()
        shutdown = pool.shutdown

        def shutdown_seen(wait: bool = True, *, cancel_futures: bool = False) -> None:
            shutdown(wait=False, cancel_futures=cancel_futures)
            cancelled.set()                        # the questions not started are cancelled now
            shutdown(wait=wait)

        pool.shutdown = shutdown_seen             # type: ignore[method-assign]
        closing = threading.Thread(target=gated.historian.close)
        closing.start()
        assert cancelled.wait(WAIT_S)
        gated.gate.set()
        closing.join(WAIT_S)
        assert not closing.is_alive()
        replies = [r for handler in pending for r in replies_of(handler)]
        assert len(replies) == 3                   # one each: an answer, or "stopping, ask again"
        errors = [json.loads(r.err.payload.to_string())["error"] for r in replies if r.err is not None]
        assert len(errors) == 2 and all("the historian is stopping: ask again" in e for e in errors)
        assert gated.questions()["waiting"] == 0
    finally:
        reader.close()


def test_a_question_over_the_time_limit_is_told_to_narrow_and_those_behind_it_to_retry(gated, monkeypatch):
    monkeypatch.setattr(zenoh_answers, "ANSWER_TIMEOUT_S", 0.5)      # the gate stays shut far longer
    reader = gated.peer()
    try:
        pending = [reader.get("edge/history/records", timeout=REPLY_S) for _ in range(3)]
        errors = [json.loads(r.err.payload.to_string()) for handler in pending for r in replies_of(handler)]
        assert len(errors) == 3 and gated.started == 1
        narrow = [e for e in errors if "narrow the question" in e["error"]]      # the one at the database
        behind = [e for e in errors if e.get("busy")]                             # those waiting behind it
        assert len(narrow) == 1 and len(behind) == 2 and all(e["refused"] is False for e in errors)
        assert all("other questions came first" in e["error"] and "retry" in e["error"] for e in behind)
        assert gated.questions() == {"answered": 0, "refused": 1, "busy": 2, "waiting": 0}
    finally:
        reader.close()
