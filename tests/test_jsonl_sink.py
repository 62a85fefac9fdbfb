"""The JSON Lines sink after a crash: torn last line removed, records repeated by a restart written once,
a controller restart with new cycle numbers not mistaken for repeats; a kill -9 of a real writer process."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

from edge_monitor.records import Symptom
from edge_monitor.sinks.jsonl import JsonlSink


def symptom(joint: int, cycle: int, robot: str = "r1") -> Symptom:
    return Symptom(robot=robot, joint=joint, cycle=cycle, t=float(cycle), friction={}, sections={}, decisions={},
                   load={}, skipped={}, critical_wear=100.0)


def lines(path: Path) -> list[dict]:
    return [json.loads(line) for line in path.read_text(encoding="utf-8").splitlines()]


def test_torn_line_is_cut_and_repeated_records_are_written_once(tmp_path: Path) -> None:
    path = tmp_path / "s.jsonl"
    sink = JsonlSink(path)
    for cycle in range(3):
        for joint in (0, 1):
            sink.on_symptom(symptom(joint, cycle))
    sink.close()
    with open(path, "a", encoding="utf-8") as fh:
        fh.write('{"schema": 1, "robot": "r1", "joint": 0, "cyc')          # killed mid-write
    sink = JsonlSink(path)
    assert sink.torn_bytes_removed > 0
    assert [(r["joint"], r["cycle"]) for r in sink.recent] == [(j, c) for c in range(3) for j in (0, 1)]
    for cycle in (1, 2, 3):                      # the restarted agent repeats what its state had not saved
        for joint in (0, 1):
            sink.on_symptom(symptom(joint, cycle))
    sink.close()
    records = lines(path)                        # every line parses
    keys = [(r["joint"], r["cycle"]) for r in records]
    assert sorted(keys) == [(j, c) for j in (0, 1) for c in range(4)]
    assert sink.duplicates_skipped == 4


def test_new_cycle_numbers_after_a_controller_restart_are_all_written(tmp_path: Path) -> None:
    path = tmp_path / "s.jsonl"
    sink = JsonlSink(path)
    for cycle in range(100, 103):
        sink.on_symptom(symptom(0, cycle))
    sink.close()
    sink = JsonlSink(path)
    for cycle in range(0, 5):                    # counters reset: lower numbers are new records
        sink.on_symptom(symptom(0, cycle))
    sink.on_symptom(symptom(0, 100, robot="other"))   # another robot's cycle 100 is not a repeat
    sink.close()
    assert len(lines(path)) == 3 + 5 + 1 and sink.duplicates_skipped == 0


_WRITER = """
import sys
from edge_monitor.records import Symptom
from edge_monitor.sinks.jsonl import JsonlSink
sink = JsonlSink(sys.argv[1])
cycle = 0
while True:
    sink.on_symptom(Symptom(robot="r1", joint=0, cycle=cycle, t=0.0, friction={"pad": ["x" * 4000]},
                            sections={}, decisions={}, load={}, skipped={}, critical_wear=100.0))
    print(cycle, flush=True)     # the point where the agent would save its state
    cycle += 1
"""


def test_kill_9_loses_no_record_the_writer_reported(tmp_path: Path) -> None:
    """A writer reports each cycle only after the sink returned (as the agent saves its state after its
    sinks); after kill -9 at an arbitrary moment, every reported cycle is in the file and the file parses."""
    path = tmp_path / "s.jsonl"
    for _ in range(3):
        proc = subprocess.Popen([sys.executable, "-c", _WRITER, str(path)], stdout=subprocess.PIPE, text=True)
        reported = []
        deadline = time.monotonic() + 60
        while len(reported) < 20 and time.monotonic() < deadline:
            reported.append(int(proc.stdout.readline()))
        os.kill(proc.pid, signal.SIGKILL)
        proc.wait(timeout=30)
        JsonlSink(path).close()                  # the restart repairs a torn tail
        written = {r["cycle"] for r in lines(path)}
        assert set(reported) <= written
