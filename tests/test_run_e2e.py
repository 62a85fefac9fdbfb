"""End-to-end across processes: frames over a pty slcan link → `edge-monitor run` (its own process)
→ Zenoh → an independent subscriber; late subscriber recovery, the state queryable, JSONL, state
file and clean shutdown on SIGTERM."""

from __future__ import annotations

import json
import signal
import subprocess
import sys
import time
from pathlib import Path

import can
import jsonschema
import pytest

from edge_monitor.schemas import load_schema
from edge_monitor.sinks.loopback import free_loopback_port as free_port
from edge_monitor.sinks.zenoh_publisher import SymptomSubscriber
from edge_monitor.sinks.zenoh_session import ZenohOptions, open_session
from protocol.links import PtyPair, open_bus

from synthetic_frames import make_frames
from waiting import wait_until

pytestmark = pytest.mark.slow

SPEEDS = (8.7, 41.7, 133.5)
CONFIG = """
robot = "cell7"
status_interval_s = 1.0
[segmentation]
speeds = [8.7, 41.7, 133.5]
[kl]
n_nominal_cycles = 2
[decision]
n_nominal = 3
density = "gauss"
quantities = ["wear", "kl_raw", "kl_weighted"]
"""


def send_frames(link: str, frames, rate_per_s: float = 8000.0) -> None:
    ids, data, dlc, ts = frames
    with open_bus(link) as bus:
        start = time.monotonic()
        for i in range(len(ids)):
            bus.send(can.Message(arbitration_id=int(ids[i]), data=bytes(data[i]), is_extended_id=False))
            if i % 200 == 0:   # pace below what slcan over a pty carries; order is all that matters
                ahead = i / rate_per_s - (time.monotonic() - start)
                if ahead > 0:
                    time.sleep(ahead)


def test_symptoms_travel_from_can_to_an_independent_zenoh_subscriber(tmp_path: Path):
    cfg = tmp_path / "agent.toml"
    cfg.write_text(CONFIG)
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    jsonl, state = tmp_path / "symptoms.jsonl", tmp_path / "state"
    # 4 cycles are sent; the 4th stays open (a live agent closes a cycle when the next begins).
    frames = make_frames(4, joints=(0, 1), speeds=SPEEDS, seed=5)
    expected = {(j, c) for j in (0, 1) for c in range(3)}
    with PtyPair() as pair:
        agent = subprocess.Popen(
            [sys.executable, "-m", "edge_monitor.cli", "run", "--link", f"slcan:{pair.b}", "--config", str(cfg),
             "--zenoh-listen", endpoint, "--jsonl", str(jsonl), "--state-dir", str(state),
             "--allow-remote-maintenance", "--json"],
            stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
        session = open_session(ZenohOptions(mode="peer", connect=[endpoint]))
        try:
            sub = SymptomSubscriber(session, "edge/cell7/**", history=True)
            assert wait_until(lambda: sub.agents, 30), "agent liveliness token not seen"
            send_frames(f"slcan:{pair.a}", frames)
            got = lambda: {(r["joint"], r["cycle"]) for r in sub.records("symptom")}  # noqa: E731
            assert wait_until(lambda: got() >= expected, 60), got()
            assert got() == expected
            # a late subscriber recovers the recent symptoms from the publisher's cache
            late_session = open_session(ZenohOptions(mode="peer", connect=[endpoint]))
            late = SymptomSubscriber(late_session, "edge/cell7/*/symptom", history=True)
            assert wait_until(lambda: {(r["joint"], r["cycle"]) for r in late.records("symptom")} >= expected, 30)
            late.close()
            late_session.close()
            # the read-only state queryable answers with the joint's detector state
            replies = list(session.get("edge/cell7/1/state", timeout=10.0))
            state_reply = json.loads(replies[0].ok.payload.to_string())
            assert state_reply["joint"] == 1 and state_reply["known"] and "detectors" in state_reply
            assert wait_until(lambda: sub.records("health"), 10)
            # a wildcard put is refused by the agent's gate (counted), an exact one makes the joint relearn
            session.put("edge/*/1/maintenance", "reset every robot")
            session.put("edge/cell7/1/maintenance", "gearbox replaced")
            session.put("edge/cell7/1/acknowledge", "{}")     # remote acknowledgements are off: refused, counted

            def maintenances() -> int:
                replies = list(session.get("edge/cell7/1/state", timeout=5.0))
                return json.loads(replies[0].ok.payload.to_string()).get("maintenances", 0) if replies else 0
            assert wait_until(lambda: maintenances() == 1, 30)
            assert wait_until(lambda: any(h.get("maintenance_refused_bad_key") == 1 and h.get("maintenance_accepted") == 1
                                          and h.get("acknowledge_refused_disabled") == 1
                                          for h in sub.records("health")), 30)
            agent.send_signal(signal.SIGTERM)
            out, _ = agent.communicate(timeout=60)
        finally:
            if agent.poll() is None:
                agent.kill()
            sub.close()
            session.close()
    assert agent.returncode == 0, out
    lines = [r for r in map(json.loads, jsonl.read_text().splitlines()) if "kind" not in r]
    assert {(r["joint"], r["cycle"]) for r in lines} == expected
    assert all(r["schema"] == 1 and r["robot"] == "cell7" for r in lines)
    saved = json.loads((state / "agent_state.json").read_text())
    assert saved["last_emitted"] == {"0": 2, "1": 2}
    health = sub.records("health")[-1]
    assert health["frames_total"] > 0 and health["crc_errors"] == 0
    # --json: the run summary (replay's schema, with the last health record) as one JSON line on stdout
    summary = json.loads([line for line in out.splitlines() if line.startswith("{")][-1])
    jsonschema.validate(summary, load_schema("summary"))
    jsonschema.validate(summary["health"], load_schema("health"))
    assert summary["health"]["robot"] == "cell7" and summary["frames_total"] >= health["frames_total"]
    assert summary["symptoms"] == len(expected) and summary["health"]["queue_dropped"] == 0
