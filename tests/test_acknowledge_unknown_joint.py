"""`edge-monitor acknowledge` for a joint the agent does not monitor: the agent's state queryable answers a
query naming that joint with an error listing the joints it monitors, and the command says so plainly
(exit 2, what to do) instead of "no agent answered" after its timeout. A joint the agent is configured for
but has learned nothing about yet is "nothing to acknowledge" (exit 0). Real Zenoh peer sessions on
loopback (multicast scouting off), a real agent's state."""

from __future__ import annotations

import json
from typing import Any

import pytest
from test_agent_pipeline import feed as feed_frames
from test_agent_pipeline import small_config

from edge_monitor.cli import main
from edge_monitor.commands.acknowledge import _not_monitored
from edge_monitor.pipeline.agent import Agent
from edge_monitor.sinks.loopback import free_loopback_port
from edge_monitor.sinks.zenoh_publisher import SymptomPublisher
from edge_monitor.sinks.zenoh_session import ZenohOptions, open_session

from synthetic_frames import make_frames

TIMEOUT_S = "30"       # the command's own bound; the verdicts below never need it to run out


@pytest.fixture(scope="module")
def agent_endpoint():
    """An agent of robot r1 configured for joints 0 and 1 that has seen only joint 0, answering state
    queries on a peer session listening on loopback."""
    agent = Agent(small_config(joints=(0, 1)))
    feed_frames(agent, make_frames(6, joints=(0,), seed=9))
    endpoint = f"tcp/127.0.0.1:{free_loopback_port()}"
    session = open_session(ZenohOptions(mode="peer", listen=[endpoint]))
    publisher = SymptomPublisher(session, "r1", (0, 1), state_provider=agent.joint_state,
                                 joints_provider=agent.known_joints)
    yield endpoint
    publisher.close()
    session.close()


def acknowledge(endpoint: str, joint: int, capsys) -> tuple[int, str, str]:
    code = main(["acknowledge", "--robot", "r1", "--joint", str(joint), "--zenoh-mode", "peer", "--zenoh-connect",
                 endpoint, "--timeout", TIMEOUT_S])
    out, err = capsys.readouterr()
    return code, out, err


def test_a_joint_the_agent_does_not_monitor_is_named_with_the_joints_it_does(agent_endpoint, capsys):
    code, out, err = acknowledge(agent_endpoint, 5, capsys)
    assert code == 2 and out == ""
    assert "--joint 5: robot r1 does not monitor joint 5 (it monitors joint(s) 0, 1)" in err
    assert "acknowledge one of those joints" in err and "restart it" in err
    assert "no agent answered" not in err and "Traceback" not in err


def test_a_configured_joint_with_nothing_learned_is_nothing_to_acknowledge(agent_endpoint, capsys):
    code, out, err = acknowledge(agent_endpoint, 1, capsys)
    assert code == 0 and "learned nothing for it yet" in out and "nothing to acknowledge" in out and err == ""


def test_a_query_of_every_joint_gets_only_the_states_and_one_named_joint_the_error(agent_endpoint):
    reader = open_session(ZenohOptions(mode="peer", connect=[agent_endpoint]))
    try:
        replies = list(reader.get("edge/r1/*/state", timeout=10))
        assert sorted(json.loads(r.ok.payload.to_bytes())["joint"] for r in replies) == [0, 1]
        [reply] = list(reader.get("edge/r1/7/state", timeout=10))
        assert reply.ok is None
        assert json.loads(reply.err.payload.to_bytes()) == {
            "error": "robot r1 does not monitor joint 7 (it monitors joint(s) 0, 1)", "unknown_joint": 7,
            "joints": [0, 1]}
    finally:
        reader.close()


class _Err:
    def __init__(self, data: bytes) -> None:
        self.err = type("Err", (), {"payload": type("P", (), {"to_bytes": lambda s: data})()})()


@pytest.mark.parametrize("data", [b"[" * 100_000 + b"]" * 100_000, b"\xff not json", b'{"error": "disk"}',
                                  b'{"error": 3, "unknown_joint": 7}', b'{"error": "x", "unknown_joint": "7"}', b"[]"])
def test_other_error_replies_are_not_taken_for_an_unmonitored_joint(data: bytes):
    assert _not_monitored(_Err(data)) is None


def test_the_agents_words_are_one_bounded_line():
    text: Any = _not_monitored(_Err(json.dumps({"error": "robot r1 does\nnot monitor " + "x" * 999,
                                                "unknown_joint": 7}).encode()))
    assert "\n" not in text and len(text) == 300
