"""``edge-monitor replay --jobs 2``: ingest in one process, the joints' monitoring in a second
(edge_monitor/monitor_process.py). The records are those of a one-process replay, byte for
byte; a monitoring process that fails or is killed stops the replay with a message, never a hang."""

from __future__ import annotations

import argparse
import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from edge_monitor.app import Outputs
from edge_monitor.commands.replay import AUTO_SPLIT_BYTES, _jobs
from edge_monitor.config import AgentConfig
from edge_monitor.monitor_process import MonitorProcess, MonitorProcessError
from edge_monitor.sources.samples import IngestBlock
from protocol.console import LOG_FORMAT


def _run(*args: str, check: bool = True) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", *args], capture_output=True, text=True, timeout=600, check=check)


@pytest.fixture(scope="module")
def faulty_log(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """3 joints, 3 cycles, with link faults (drops, corruptions, duplicates, reordering) and a wear ramp."""
    log = tmp_path_factory.mktemp("split") / "faults.blf"
    _run("sim_controller.cli", "record", "--out", str(log), "--joints", "3", "--cycles", "3", "--seed", "12",
         "--faults", "drop=0.002,corrupt=0.002,duplicate=0.001,reorder=0.001")
    return log


def _timeless(stats: dict) -> dict:
    return {k: v for k, v in stats.items() if k not in ("wall_s", "frames_per_second")}


def test_two_processes_publish_what_one_does(faulty_log: Path, tmp_path: Path) -> None:
    outs = {}
    for jobs in ("1", "2"):
        jsonl = tmp_path / f"jobs{jobs}.jsonl"
        done = _run("edge_monitor.cli", "replay", str(faulty_log), "--json", "--jsonl", str(jsonl), "--jobs", jobs)
        outs[jobs] = (json.loads(done.stdout), jsonl.read_bytes())
    (one, records_one), (two, records_two) = outs["1"], outs["2"]
    assert records_one == records_two and records_one.count(b"\n") >= 9        # 3 joints × 3 cycles at least
    assert _timeless(one) == _timeless(two)
    assert one["crc_errors"] > 0 and one["counter_lost"] > 0                  # the faults did reach the ingest


def test_the_summary_table_is_the_same(faulty_log: Path) -> None:
    tables = [_run("edge_monitor.cli", "replay", str(faulty_log), "--jobs", jobs).stdout for jobs in ("1", "2")]
    strip = [[line for line in t.splitlines() if "frames/s" not in line] for t in tables]
    assert strip[0] == strip[1] and len(strip[0]) > 3


def test_a_state_file_or_an_unwritable_output_is_said_not_hidden(faulty_log: Path, tmp_path: Path) -> None:
    with_state = _run("edge_monitor.cli", "replay", str(faulty_log), "--jobs", "2", "--state",
                      str(tmp_path / "state.json"), check=False)
    assert with_state.returncode == 2 and "--jobs 1" in with_state.stderr and "Traceback" not in with_state.stderr
    unwritable = _run("edge_monitor.cli", "replay", str(faulty_log), "--jobs", "2", "--jsonl", str(tmp_path),
                      check=False)
    single = _run("edge_monitor.cli", "replay", str(faulty_log), "--jobs", "1", "--jsonl", str(tmp_path),
                  check=False)
    assert unwritable.returncode == single.returncode == 1
    assert "Traceback" not in unwritable.stderr and str(tmp_path) in unwritable.stderr


def _monitor() -> MonitorProcess:
    return MonitorProcess(AgentConfig(), Outputs(), 30, LOG_FORMAT)


def test_a_failing_monitoring_process_stops_the_replay_with_its_error() -> None:
    monitor = _monitor()
    try:
        assert monitor.setup is None
        monitor.update(IngestBlock())
        monitor.update("not a block")                    # type: ignore[arg-type]  # breaks the child's agent
        with pytest.raises(MonitorProcessError, match="failed \\(AttributeError: .*--jobs 1"):
            monitor.finish(True, {"frames_total": 0}, {"no_new_data": 0})
    finally:
        monitor.close()


def test_a_killed_monitoring_process_stops_the_replay_instead_of_hanging() -> None:
    monitor = _monitor()
    try:
        assert monitor.pid is not None
        os.kill(monitor.pid, signal.SIGKILL)
        with pytest.raises(MonitorProcessError, match="exited unexpectedly.*--jobs 1"):
            for _ in range(10_000):                      # the queue fills, then the dead child is noticed
                monitor.update(IngestBlock())
            monitor.finish(True, {"frames_total": 0}, {"no_new_data": 0})
    finally:
        monitor.close()


def test_auto_splits_large_logs_only_without_a_state_file(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    small, large = tmp_path / "small.blf", tmp_path / "large.blf"
    small.write_bytes(b"\0" * 1024)
    with open(large, "wb") as f:
        f.truncate(AUTO_SPLIT_BYTES)                     # sparse: no disk used
    monkeypatch.setattr(os, "cpu_count", lambda: 2)
    args = lambda path, jobs="auto": argparse.Namespace(file=str(path), jobs=jobs)  # noqa: E731
    assert _jobs(args(small), None) == 1 and _jobs(args(large), None) == 2
    assert _jobs(args(large), store=object()) == 1 and _jobs(args(small, "2"), None) == 2
    assert _jobs(args(tmp_path / "missing.blf"), None) == 1
    monkeypatch.setattr(os, "cpu_count", lambda: 1)
    assert _jobs(args(large), None) == 1


def test_a_killed_replay_does_not_leave_its_monitoring_process_behind(tmp_path: Path) -> None:
    """kill -9 of the replay: its monitoring process notices within a poll and exits, closing its
    outputs (the JSONL file is whole up to its last record), instead of waiting forever."""
    script = tmp_path / "parent.py"
    script.write_text(
        "import sys, time\n"
        "from edge_monitor.app import Outputs\n"
        "from edge_monitor.config import AgentConfig\n"
        "from edge_monitor.monitor_process import MonitorProcess\n"
        "from protocol.console import LOG_FORMAT\n"
        "if __name__ == '__main__':\n"                      # the child is spawned: it imports this file
        f"    m = MonitorProcess(AgentConfig(), Outputs(jsonl={str(tmp_path / 'out.jsonl')!r}), 30, LOG_FORMAT)\n"
        "    print(m.pid, flush=True)\n"
        "    time.sleep(600)\n")
    parent = subprocess.Popen([sys.executable, str(script)], stdout=subprocess.PIPE, text=True)
    child = 0
    try:
        child = int(parent.stdout.readline())
        os.kill(parent.pid, signal.SIGKILL)
        parent.wait(timeout=30)
        for _ in range(600):                                 # ≤ 60 s; a poll is 1 s
            if not _alive(child):
                break
            time.sleep(0.1)
        assert not _alive(child), "the monitoring process outlived the replay"
    finally:
        parent.kill()
        if child and _alive(child):
            os.kill(child, signal.SIGKILL)


def _alive(pid: int) -> bool:
    """Whether ``pid`` runs (a zombie, reaped by init soon, counts as gone)."""
    try:
        with open(f"/proc/{pid}/stat") as f:
            return f.read().split(") ")[1][0] != "Z"
    except (FileNotFoundError, IndexError):
        return False
