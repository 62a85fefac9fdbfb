"""Hostile input around acknowledgements: a state reply or alarm record nested deeper than the JSON parser
recurses is an invalid reply (one line, no traceback), and line or paragraph separators and invisible
format characters in ``by``/``note`` are refused like control characters (they could forge a log line)."""

from __future__ import annotations

import json
import time

import pytest

from edge_monitor.commands.acknowledge import _Acknowledged, _joint_state
from edge_monitor.sinks.acknowledge import AcknowledgeRequest, parse_request

DEEP = b"[" * 200_000 + b"]" * 200_000


class _Payload:
    def __init__(self, data: bytes) -> None:
        self.data = data

    def to_bytes(self) -> bytes:
        return self.data


class _Reply:
    def __init__(self, data: bytes) -> None:
        self.ok = type("Ok", (), {"payload": _Payload(data)})()


class _Session:
    """Answers the state query with a deep reply first, a real state after; keeps the subscriber's callback."""

    def __init__(self, replies: list[bytes]) -> None:
        self.replies = replies
        self.callback = None

    def get(self, _key: str, timeout: float) -> list[_Reply]:
        return [_Reply(self.replies.pop(0))] if self.replies else []

    def declare_subscriber(self, _key: str, callback):
        self.callback = callback
        return type("Subscriber", (), {"undeclare": lambda s: None})()


def test_a_deeply_nested_state_reply_is_an_invalid_reply_and_a_good_one_after_it_is_used(capsys):
    session = _Session([DEEP, DEEP, json.dumps({"detectors": {}}).encode()])
    state = _joint_state(session, "r1", 0, time.monotonic() + 600)
    assert state == {"detectors": {}}
    err = capsys.readouterr().err
    assert err.count("ignored an invalid state reply on edge/r1/0/state") == 1 and "Traceback" not in err


def test_a_deeply_nested_alarm_record_is_ignored_and_a_real_acknowledgement_counts():
    session = _Session([])
    listener = _Acknowledged(session, "edge/r1/0/alarm")
    sample = type("Sample", (), {"payload": _Payload(DEEP)})()
    session.callback(sample)
    assert listener.records == []
    record = {"state": "acknowledged", "quantity": "wear", "cycle": 3}
    session.callback(type("Sample", (), {"payload": _Payload(json.dumps(record).encode())})())
    assert listener.wait_for({"wear"}, time.monotonic() + 600) == [record]


@pytest.mark.parametrize("text", ["alice\u2028WARNING forged", "alice\u2029x", "ali\u200bce", "\u202eecila",
                                  "alice\u0085x", "alice\ufeff"])
@pytest.mark.parametrize("field", ["by", "note"])
def test_separators_and_invisible_format_characters_are_refused(field, text):
    with pytest.raises(ValueError, match=f"{field}: control characters are not allowed"):
        parse_request(json.dumps({field: text}).encode())


def test_ordinary_names_and_notes_still_pass():
    request = parse_request('{"by": "Zoë Ñúñez-O\'Brien", "note": "probe knocked the arm — twice, 3 µm"}'.encode())
    assert request == AcknowledgeRequest(None, "Zoë Ñúñez-O'Brien", "probe knocked the arm — twice, 3 µm")
