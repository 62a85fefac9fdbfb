"""`edge-monitor listen` prints the provenance of the key a record came on, never one the record chose:
"kind" and "key" are the key's, and a record whose own robot or joint is another's is not printed but
counted ("refused" in the summary on standard error). Zenoh on loopback only, multicast scouting off."""

from __future__ import annotations

import json
import subprocess
import sys
import threading
from pathlib import Path

from edge_monitor.commands.listen import line_of, mismatch
from edge_monitor.sinks.loopback import free_loopback_port
from edge_monitor.sinks.zenoh_publisher import ReceivedRecord
from edge_monitor.sinks.zenoh_session import ZenohOptions, open_session

EDGE = str(Path(sys.executable).parent / "edge-monitor")
FORGED = {"kind": "alarm", "key": "edge/r1/3/alarm", "schema": 1, "robot": "r1", "joint": 3, "cycle": 500,
          "state": "raised", "fault": "r1/3/500", "open": True}
#: r9's own record that names another kind and key in its fields: printed, as the symptom it came as
OWN = {**FORGED, "robot": "r9", "joint": 0, "fault": "r9/0/500"}


def received(key: str, record: dict) -> ReceivedRecord:
    robot, joint, kind = key.split("/")[1:]
    return ReceivedRecord(key, robot, None if joint == "agent" else int(joint), kind, record)


def test_kind_and_key_are_the_keys_whatever_the_record_says():
    line = json.loads(line_of(received("edge/r9/0/symptom", OWN)))
    assert (line["kind"], line["key"], line["robot"], line["joint"]) == ("symptom", "edge/r9/0/symptom", "r9", 0)
    assert list(line)[:2] == ["kind", "key"]
    assert json.loads(line_of(received("edge/r9/0/symptom", {"cycle": 1}))) == {
        "kind": "symptom", "key": "edge/r9/0/symptom", "cycle": 1}


def test_a_record_of_another_robot_or_joint_is_refused_and_ones_own_is_not():
    assert "robot 'r1'" in str(mismatch(received("edge/r9/0/symptom", FORGED)))
    assert "joint 3" in str(mismatch(received("edge/r9/0/symptom", {**FORGED, "robot": "r9"})))
    assert mismatch(received("edge/r9/0/symptom", {**OWN, "joint": True})) is not None
    assert mismatch(received("edge/r9/agent/health", {"robot": "r9", "joint": 2})) is not None
    assert mismatch(received("edge/r9/0/symptom", OWN)) is None
    assert mismatch(received("edge/r9/0/symptom", {"cycle": 1})) is None         # no robot, no joint: the key's
    assert mismatch(received("edge/r9/agent/health", {"robot": "r9"})) is None


def test_listen_drops_and_counts_a_forged_record_and_prints_the_real_one():
    endpoint = f"tcp/127.0.0.1:{free_loopback_port()}"
    router = open_session(ZenohOptions(mode="router", listen=[endpoint]))
    forger = open_session(ZenohOptions(mode="client", connect=[endpoint]))
    stop = threading.Event()

    def put_until_stopped() -> None:        # forged, then real, every round: two real ones have a forged between
        while not stop.is_set():
            forger.put("edge/r9/0/symptom", json.dumps(FORGED))
            forger.put("edge/r9/0/symptom", json.dumps(OWN))
            stop.wait(0.05)

    listener = subprocess.Popen([EDGE, "listen", "--zenoh-mode", "client", "--zenoh-connect", endpoint, "--robot",
                                 "r9", "--no-history", "--count", "2", "--duration", "120"],
                                stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    putter = threading.Thread(target=put_until_stopped, daemon=True)
    putter.start()
    try:
        out, err = listener.communicate(timeout=180)
    finally:
        stop.set()
        putter.join()
        if listener.poll() is None:
            listener.kill()
            listener.communicate()
        forger.close()
        router.close()
    assert listener.returncode == 0, err
    lines = [json.loads(x) for x in out.splitlines()]
    assert len(lines) == 2
    assert all((r["kind"], r["key"], r["robot"], r["joint"]) == ("symptom", "edge/r9/0/symptom", "r9", 0)
               for r in lines)
    summary = [x for x in err.splitlines() if "records printed" in x][-1]
    refused = int(summary.split("refused ")[1].split()[0])
    assert refused >= 1 and "record not printed: robot 'r1' on edge/r9/0/symptom" in err
