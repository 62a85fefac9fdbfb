"""One behaviour at the end of a stream: `edge-monitor run` stopped by --idle-stop publishes the same
symptoms as `edge-monitor replay` of the same frames (the last cycle closed); --no-close leaves it
open in both."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import can
import pytest
from test_run_e2e import CONFIG, SPEEDS, send_frames

from protocol.links import PtyPair

from synthetic_frames import make_frames
from waiting import wait_until

pytestmark = pytest.mark.slow

CYCLES, JOINTS = 3, (0, 1)


def _keys(jsonl: Path) -> list[tuple[int, int]]:
    return sorted((r["joint"], r["cycle"]) for r in map(json.loads, jsonl.read_text().splitlines()) if "kind" not in r)


def _write_log(path: Path, frames) -> None:
    ids, data, _, ts = frames
    with can.Logger(str(path)) as logger:
        for i in range(len(ids)):
            logger.on_message_received(can.Message(timestamp=float(ts[i]), arbitration_id=int(ids[i]),
                                                   data=bytes(data[i]), is_extended_id=False))


def _run_live(tmp_path: Path, name: str, frames, *extra: str) -> tuple[list[tuple[int, int]], dict]:
    jsonl = tmp_path / f"{name}.jsonl"
    with PtyPair() as pair:
        agent = subprocess.Popen(
            [sys.executable, "-m", "edge_monitor.cli", "run", "--link", f"slcan:{pair.b}", "--config",
             str(tmp_path / "agent.toml"), "--no-zenoh", "--jsonl", str(jsonl), "--idle-stop", "3",
             "--json", *extra], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
        try:   # frames sent before the agent opened its end would be discarded (a serial line)
            assert wait_until(lambda: pair.is_open(pair.b), 60), "the agent did not open its end of the link"
            send_frames(f"slcan:{pair.a}", frames)
            out, err = agent.communicate(timeout=300)
        finally:
            if agent.poll() is None:
                agent.kill()
    assert agent.returncode == 0, err
    summary = json.loads([line for line in out.splitlines() if line.startswith("{")][-1])
    return _keys(jsonl), summary


@pytest.fixture(scope="module")
def recorded(tmp_path_factory):
    tmp_path = tmp_path_factory.mktemp("end_of_stream")
    (tmp_path / "agent.toml").write_text(CONFIG)
    frames = make_frames(CYCLES, joints=JOINTS, speeds=SPEEDS, seed=13)
    log = tmp_path / "frames.log"
    _write_log(log, frames)
    return tmp_path, frames, log


def _replay(tmp_path: Path, log: Path, name: str, *extra: str) -> list[tuple[int, int]]:
    jsonl = tmp_path / f"{name}.jsonl"
    result = subprocess.run([sys.executable, "-m", "edge_monitor.cli", "replay", str(log), "--config",
                             str(tmp_path / "agent.toml"), "--jsonl", str(jsonl), "-q", *extra],
                            capture_output=True, text=True, timeout=300)
    assert result.returncode == 0, result.stderr
    return _keys(jsonl)


def test_run_to_the_end_of_the_stream_publishes_what_replay_publishes(recorded):
    tmp_path, frames, log = recorded
    every_cycle = [(j, c) for j in JOINTS for c in range(CYCLES)]
    assert _replay(tmp_path, log, "replay") == every_cycle
    live, summary = _run_live(tmp_path, "live", frames)
    assert live == every_cycle and summary["symptoms"] == len(every_cycle) and summary["cycles"] == CYCLES


def test_no_close_leaves_the_last_cycle_open_in_both(recorded):
    tmp_path, frames, log = recorded
    completed = [(j, c) for j in JOINTS for c in range(CYCLES - 1)]
    assert _replay(tmp_path, log, "replay-open", "--no-close") == completed
    live, _ = _run_live(tmp_path, "live-open", frames, "--no-close")
    assert live == completed
