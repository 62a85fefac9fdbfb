"""The JSON Lines sink after a crash: torn last line removed, records repeated by a restart written once,
a controller restart with new cycle numbers not mistaken for repeats; a kill -9 of a real writer process."""

from __future__ import annotations

import errno
import json
import os
import signal
import stat as stat_module
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


# -- issue 28: the disk fills, files lie ------------------------------------------------------------

import pytest  # noqa: E402
from hypothesis import HealthCheck, given, settings  # noqa: E402
from hypothesis import strategies as st  # noqa: E402

from edge_monitor.sinks import jsonl as jsonl_module  # noqa: E402
from edge_monitor.sinks.jsonl import JsonlOpenError, Rotation, rotated_path  # noqa: E402


def test_a_torn_tail_longer_than_the_tail_window_is_repaired(tmp_path: Path) -> None:
    """A crash can leave any length of unterminated record: 3 MiB of it (three tail windows) is cut,
    and the next record starts on its own line."""
    path = tmp_path / "s.jsonl"
    sink = JsonlSink(path)
    sink.on_symptom(symptom(0, 0))
    sink.close()
    with open(path, "a", encoding="utf-8") as fh:
        fh.write('{"schema": 1, "pad": "' + "x" * (3 << 20))
    sink = JsonlSink(path)
    assert sink.torn_bytes_removed > 3 << 20
    sink.on_symptom(symptom(0, 1))
    sink.close()
    assert [(r["joint"], r["cycle"]) for r in lines(path)] == [(0, 0), (0, 1)]


@pytest.mark.parametrize("line", [
    b'{"robot":"robot1","joint":[1],"cycle":1}',           # unhashable joint: stopped replay (TypeError)
    b'{"robot":{"a":1},"joint":1,"cycle":1}', b'{"robot":"r1","joint":true,"cycle":1}',
    b'{"robot":"r1","joint":1,"cycle":' + b"9" * 5000 + b"}", b"[" * 5000 + b"]" * 5000,
    b"[1, 2]", b'"text"', b"null", b"{}", b'{"robot":"r1","joint":1.5,"cycle":2}',
])
def test_hostile_lines_in_the_tail_are_counted_and_ignored(tmp_path: Path, line: bytes) -> None:
    path = tmp_path / "s.jsonl"
    path.write_bytes(b'{"schema":1,"robot":"r1","joint":0,"cycle":7}\n' + line + b"\n")
    sink = JsonlSink(path)
    assert sink.unusable_tail_lines == 1 and [r["cycle"] for r in sink.recent] == [7]
    sink.on_symptom(symptom(0, 7))                      # the valid one is still recognised as a repeat
    sink.on_symptom(symptom(1, 1))
    sink.close()
    assert sink.duplicates_skipped == 1 and sink.written == 1


@pytest.mark.parametrize("target", ["/dev/full", "/dev/zero", "/dev/null", "directory", "fifo", "not-jsonl"])
def test_only_a_regular_json_lines_file_is_opened(tmp_path: Path, target: str) -> None:
    """/dev/full and /dev/zero were opened (and /dev/zero read to the end); a FIFO blocked."""
    if target.startswith("/dev/"):
        path = Path(target)
    elif target == "directory":
        path = tmp_path
    elif target == "fifo":
        path = tmp_path / "f.jsonl"
        os.mkfifo(path)
    else:
        path = tmp_path / "notes.txt"
        path.write_text("my notes, not symptoms\n")
    with pytest.raises(JsonlOpenError):
        JsonlSink(path, strict=True)
    sink = JsonlSink(path)                                # not strict: every record counted as a failure
    sink.on_symptom(symptom(0, 0))
    assert sink.failures == 1 and sink.written == 0
    if target == "not-jsonl":
        assert path.read_text() == "my notes, not symptoms\n"


def test_a_write_that_fails_midway_leaves_the_last_complete_record(tmp_path: Path, monkeypatch) -> None:
    """ENOSPC after half a line (a disk that fills during the write): the half line is cut off again,
    the failure counted; the next write, once there is space, continues the file cleanly."""
    path = tmp_path / "s.jsonl"
    sink = JsonlSink(path)
    sink.on_symptom(symptom(0, 0))
    real_write = os.write
    calls = {"n": 0}

    def full_disk(fd: int, data) -> int:
        calls["n"] += 1
        if calls["n"] == 1:
            return real_write(fd, bytes(data[: len(data) // 2]))
        raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))

    monkeypatch.setattr(jsonl_module.os, "write", full_disk)
    sink.on_symptom(symptom(0, 1))
    sink.on_symptom(symptom(0, 2))
    monkeypatch.setattr(jsonl_module.os, "write", real_write)
    sink.on_symptom(symptom(0, 3))
    sink.close()
    assert sink.failures == 2 and sink.written == 2
    assert [r["cycle"] for r in lines(path)] == [0, 3]


def test_rotation_keeps_whole_records_and_the_newest_files(tmp_path: Path) -> None:
    """Each file stays under max_bytes and holds whole records; PATH.1 … PATH.keep are the newest older
    ones; a restart right after a rotation still finds its repeats in PATH.1."""
    path = tmp_path / "s.jsonl"
    rotation = Rotation(max_bytes=1 << 16, keep=2)
    sink = JsonlSink(path, rotation=rotation)
    big = [symptom(0, c) for c in range(60)]
    for s in big:
        s.friction["pad"] = ["x" * 4000]
        sink.on_symptom(s)
    sink.close()
    files = [path, rotated_path(path, 1), rotated_path(path, 2)]
    assert all(f.exists() for f in files) and not rotated_path(path, 3).exists()
    assert sink.rotations >= 3
    cycles = []
    for f in reversed(files):
        assert f.stat().st_size <= rotation.max_bytes
        cycles += [r["cycle"] for r in lines(f)]           # every line parses: nothing torn
    assert cycles == sorted(cycles) and cycles[-1] == 59 and len(cycles) == len(set(cycles))
    path.write_bytes(b"")                                   # as if the crash came right after a rotation
    restarted = JsonlSink(path, rotation=rotation)
    last_in_older = [r["cycle"] for r in lines(rotated_path(path, 1))][-1]
    restarted.on_symptom(symptom(0, last_in_older))
    restarted.close()
    assert restarted.duplicates_skipped == 1


def test_rotation_settings_are_validated() -> None:
    from edge_monitor.errors import ConfigError
    for max_bytes, keep in ((100, 5), (-1, 5), (1 << 16, 0), (1 << 16, 10_000), (1 << 50, 3)):
        with pytest.raises(ConfigError):
            Rotation(max_bytes, keep)


_HUP_WRITER = """
import signal, sys
from edge_monitor.records import Symptom
from edge_monitor.sinks.jsonl import JsonlSink
sink = JsonlSink(sys.argv[1])
signal.signal(signal.SIGHUP, lambda *_: sink.request_reopen())
for cycle in range(int(sys.argv[2])):
    sink.on_symptom(Symptom(robot="r1", joint=0, cycle=cycle, t=0.0, friction={"pad": ["x" * 2000]},
                            sections={}, decisions={}, load={}, skipped={}, critical_wear=100.0))
    print(cycle, flush=True)
    if cycle % 50 == 49 and cycle < int(sys.argv[2]) - 1:
        sys.stdin.readline()          # the test rotates the file meanwhile
sink.close()
"""


def test_logrotate_rename_and_sighup_lose_and_tear_nothing(tmp_path: Path) -> None:
    """logrotate's way (rename the file, then SIGHUP the writer): records written before the signal
    are in the renamed file, those after it in a new PATH; together every cycle once, every line whole."""
    path = tmp_path / "s.jsonl"
    proc = subprocess.Popen([sys.executable, "-c", _HUP_WRITER, str(path), "200"], stdin=subprocess.PIPE,
                            stdout=subprocess.PIPE, text=True)
    try:
        for rotation in range(1, 4):
            while int(proc.stdout.readline()) % 50 != 49:
                pass
            os.replace(path, tmp_path / f"s.jsonl.{rotation}")
            os.kill(proc.pid, signal.SIGHUP)
            proc.stdin.write("\n")
            proc.stdin.flush()
        assert proc.wait(timeout=120) == 0
    finally:
        proc.kill()
    files = [tmp_path / f"s.jsonl.{k}" for k in (1, 2, 3)] + [path]
    per_file = [[r["cycle"] for r in lines(f)] for f in files]
    assert [c for cycles in per_file for c in cycles] == list(range(200))
    assert all(cycles for cycles in per_file)              # each file got records: the reopen happened


@settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(tail=st.binary(max_size=3000), records=st.integers(0, 3))
def test_any_tail_opens_cleanly_or_is_refused(tmp_path: Path, tail: bytes, records: int) -> None:
    """Whatever a file ends with (any bytes after complete records): opening either refuses it
    (JsonlOpenError: not JSON Lines) or repairs it so that the next record is a whole last line."""
    path = tmp_path / "fuzz.jsonl"
    path.write_bytes(b"".join(b'{"robot":"r1","joint":0,"cycle":%d}\n' % c for c in range(records)) + tail)
    try:
        sink = JsonlSink(path, strict=True)
    except JsonlOpenError:
        assert records == 0 and not tail.startswith(b"{")
        return
    sink.on_symptom(symptom(3, 1000))
    sink.close()
    data = path.read_bytes()
    assert data.endswith(b"\n") and json.loads(data.splitlines()[-1])["cycle"] == 1000
    assert stat_module.S_ISREG(path.stat().st_mode)


def test_sighup_makes_the_agents_jsonl_output_reopen(tmp_path: Path) -> None:
    """`edge-monitor run` installs the handler: SIGHUP asks every JSONL output to reopen its path."""
    from edge_monitor.commands.run import install_reopen_on_hangup

    sink = JsonlSink(tmp_path / "s.jsonl")
    app = type("App", (), {"sinks": [sink]})()
    previous = signal.getsignal(signal.SIGHUP)
    try:
        install_reopen_on_hangup(app)
        os.replace(tmp_path / "s.jsonl", tmp_path / "s.jsonl.1")      # logrotate: rename, then signal
        os.kill(os.getpid(), signal.SIGHUP)
        sink.on_symptom(symptom(0, 0))
    finally:
        signal.signal(signal.SIGHUP, previous)
        sink.close()
    assert sink.reopens == 1 and [r["cycle"] for r in lines(tmp_path / "s.jsonl")] == [0]
    assert (tmp_path / "s.jsonl.1").read_bytes() == b""


def test_records_are_fsynced_in_groups_and_always_before_a_state_save(tmp_path: Path, monkeypatch) -> None:
    """Group commit: with a clock that does not move, 50 records cost no fsync until a sync, a close or
    the interval passes; an agent with a state store syncs the JSONL before every state save, so the state
    never counts a record that a power cut could take."""
    from test_agent_pipeline import small_config

    from edge_monitor.pipeline.agent import Agent
    from edge_monitor.pipeline.state_store import StateStore
    from edge_monitor.sinks import jsonl as jsonl_module

    calls: list[str] = []
    real_fsync = os.fsync

    def fsync(fd: int) -> None:                       # os is one module: the state store's fsyncs come here too
        if os.readlink(f"/proc/self/fd/{fd}").endswith(".jsonl"):
            calls.append("jsonl")
        real_fsync(fd)

    monkeypatch.setattr(jsonl_module.os, "fsync", fsync)
    now = [0.0]
    sink = JsonlSink(tmp_path / "s.jsonl", clock=lambda: now[0])
    for cycle in range(50):
        sink.on_symptom(symptom(0, cycle))
    assert calls == [] and sink.written == 50
    sink.sync()
    sink.sync()                                       # nothing new: no second fsync
    assert calls == ["jsonl"] and sink.fsyncs == 1
    now[0] = 0.5
    sink.on_symptom(symptom(0, 50))
    assert calls == ["jsonl"]
    now[0] = 1.0 + 1e-9                               # the interval has passed since the last sync
    sink.on_symptom(symptom(0, 51))
    assert calls == ["jsonl"] * 2
    sink.on_symptom(symptom(0, 52))
    sink.close()
    assert calls == ["jsonl"] * 3 and len(lines(tmp_path / "s.jsonl")) == 53

    calls.clear()
    sink = JsonlSink(tmp_path / "t.jsonl", clock=lambda: 0.0)
    store = StateStore(tmp_path / "state")
    real_save = store.save
    monkeypatch.setattr(store, "save", lambda state: (calls.append("state"), real_save(state))[1])
    agent = Agent(small_config(), sinks=[sink], state_store=store)
    sink.on_symptom(symptom(1, 0))
    assert agent.save_state() and calls == ["jsonl", "state"]
    assert agent.save_state() and calls == ["jsonl", "state", "state"]      # nothing new to sync
