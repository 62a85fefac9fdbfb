"""Across processes, as on a plant floor: `sim-controller run --profile cia402 | dbc:…` → slcan over a pty
→ `edge-monitor run --mapping …` (listen-only). The agent decodes the drives' TPDOs (canopen layout) and the
foreign DBC (cantools layout), publishes symptoms of the cycles it finds from the motion, and sends no
frame on the bus: every byte the agent's end writes is watched on the pty bridge. Real time: a foreign
controller has no tick counter, so the agent takes time from the receive timestamps."""

from __future__ import annotations

import json
import subprocess
import sys
import threading
from pathlib import Path

import pytest

from protocol.links import PtyPair

from foreign_mappings import SPEEDS, mapping
from waiting import wait_until

pytestmark = pytest.mark.slow
CYCLES = 3
#: slcan lines that put a frame on the bus (data or remote, 11- or 29-bit, classical or FD).
FRAME_COMMANDS = tuple(b"tTrRdDbB")


class BusTap:
    """Bytes travelling towards the simulator's end: whatever the agent's end writes."""

    def __init__(self, end: str) -> None:
        self.end, self.data, self.lock = end, bytearray(), threading.Lock()

    def queued(self, end: str, data: bytes) -> None:
        if end == self.end:
            with self.lock:
                self.data += data

    def lost(self, end: str, data: bytes, reason: str) -> None:
        self.queued(end, data)

    def undelivered(self, end: str, start: int, stop: int) -> None:
        pass

    def closed(self, end: str) -> None:
        pass

    def frames(self) -> list[bytes]:
        with self.lock:
            lines = bytes(self.data).replace(b"\r", b"\n").split(b"\n")
        return [line for line in lines if line and line[0] in FRAME_COMMANDS]


@pytest.mark.parametrize("profile", ["cia402", "foreign_robot"])
def test_agent_beside_a_foreign_controller_listens_only(tmp_path: Path, profile: str):
    m = mapping(profile, tmp_path)
    jsonl = tmp_path / "symptoms.jsonl"
    sim_profile = "cia402" if profile == "cia402" else f"dbc:{m}"
    tap_end: list[str] = []
    tap = BusTap("")
    with PtyPair(observer=tap) as pair:
        tap.end = pair.a
        tap_end.append(pair.a)
        agent = subprocess.Popen(
            [sys.executable, "-m", "edge_monitor.cli", "run", "--link", f"slcan:{pair.b}", "--mapping", str(m),
             "--no-zenoh", "--jsonl", str(jsonl), "--idle-stop", "3", "--summary-json"],
            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
        try:
            assert wait_until(lambda: pair.is_open(pair.b), 60), "the agent did not open its end"
            subprocess.run([sys.executable, "-m", "sim_controller.cli", "run", "--link", f"slcan:{pair.a}",
                            "--profile", sim_profile, "--joints", "2", "--cycles", str(CYCLES), "--seed", "6",
                            "--speeds", ",".join(map(str, SPEEDS)), "--realtime", "-q"], check=True, timeout=300)
            out, err = agent.communicate(timeout=300)
        finally:
            if agent.poll() is None:
                agent.kill()
                agent.wait()
    assert agent.returncode == 0, err
    summary = json.loads(out.strip().splitlines()[-1])
    health = {**summary, **summary["health"]}          # the run summary, and its last health record
    assert health["frames_total"] > 10_000 and health["unknown_id"] == 0 and health["queue_dropped"] == 0
    assert health["cycle_finding"]["cycles_found"] == CYCLES, (health, err)
    records = [r for r in map(json.loads, jsonl.open()) if "kind" not in r]      # symptoms, not alarm events
    assert {(r["joint"], r["cycle"]) for r in records} == {(j, c) for j in (0, 1) for c in range(CYCLES)}
    # receive timestamps jitter on a loaded machine: a plateau may be cut short now and then (counted)
    measured = sum(len(r["friction"]["torque"]) for r in records)
    assert measured >= 0.8 * len(SPEEDS) * len(records), [r["friction"]["speeds"] for r in records]
    assert tap.frames() == [], "the agent sent frames on the bus"
