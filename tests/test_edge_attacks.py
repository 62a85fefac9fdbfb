"""Edges found by an attack pass on the state directory, the outputs and the frame times (round s16), each as
small as it can be: a frame time beyond the year 9999, a ``replayed_input.json`` edited by hand, a FIFO where the
replay writes its note, standard output that cannot be written (``> /dev/full``, a reader gone), and a JSONL file
deleted or renamed while the agent writes it. Before: a traceback, a hang, or records written to a file no one
could read any more."""

from __future__ import annotations

import json
import logging
import os
import subprocess
import sys
import threading
from pathlib import Path

import numpy as np
import pytest

from edge_monitor.commands.replay import REPLAYED_FILE, InputTimes
from edge_monitor.records import LATEST_WALL_TIME, Symptom, utc_text
from edge_monitor.sinks.jsonl import JsonlSink
from protocol.console import guarded_stdout, stdout_failure_exit

EM = [sys.executable, "-m", "edge_monitor.cli"]
SIM = [sys.executable, "-m", "sim_controller.cli"]
START = 1.7e9            # an absolute frame time (2023-11-14)


def _symptom(cycle: int) -> Symptom:
    return Symptom(robot="r1", joint=0, cycle=cycle, t=float(cycle), friction={}, sections={}, decisions={},
                   load={}, skipped={}, critical_wear=100.0)


def _cycles(path: Path) -> list[int]:
    return [json.loads(line)["cycle"] for line in path.read_text(encoding="utf-8").splitlines()]


# ------------------------------------------------------------------------------ 1: frame times beyond year 9999
@pytest.mark.parametrize("stamp", [1e13, 1e17, LATEST_WALL_TIME, float("inf"), 1e308])
def test_a_time_no_calendar_can_write_gives_no_utc(stamp):
    """datetime raised ValueError (year 318911) or OSError (EOVERFLOW) out of every symptom of such a log."""
    assert utc_text(stamp) is None
    assert utc_text(LATEST_WALL_TIME - 1) == "9999-12-31T23:59:59.000Z"


@pytest.mark.slow
def test_a_log_whose_clock_jumps_ten_thousand_years_replays(tmp_path):
    """The second half of a text log 10¹³ s later: replayed to the end, its records with ``"utc": null``."""
    log = tmp_path / "run.log"
    subprocess.run([*SIM, "record", "--out", str(log), "--joints", "1", "--cycles", "2", "--start-time",
                    str(int(START)), "-q"], check=True, timeout=300)
    lines = log.read_text().splitlines()
    half = len(lines) // 2
    jumped = [f"({float(line[1:line.index(')')]) + 1e13:.6f}){line[line.index(')') + 1:]}" for line in lines[half:]]
    log.write_text("\n".join(lines[:half] + jumped) + "\n")
    jsonl = tmp_path / "s.jsonl"
    done = subprocess.run([*EM, "replay", str(log), "--json", "--jsonl", str(jsonl), "--state-dir",
                           str(tmp_path / "state")], capture_output=True, text=True, timeout=300)
    assert done.returncode == 0 and "Traceback" not in done.stderr, done.stderr[-3000:]
    records = [json.loads(line) for line in jsonl.read_text().splitlines()]
    assert [r["cycle"] for r in records] == [0, 1] and records[-1]["utc"] is None


# ------------------------------------------------------------------------------ 2: the replay's note in the state dir
@pytest.mark.parametrize("text", ['{"input": "x", "last_time": 1e308}', '{"input": "x", "last_time": 1' + "0" * 400 + "}",
                                  '{"input": "x", "last_time": true}', "[" * 100_000, '{"input": [1], "last_time": NaN}'])
def test_a_replayed_input_note_edited_by_hand_is_ignored(tmp_path, text):
    """A last time of 1e308 or of 400 digits made the next replay of an absolute log end in a traceback."""
    (tmp_path / REPLAYED_FILE).write_text(text)
    times = InputTimes(tmp_path, "run.blf")
    assert times.before == {}
    times.see(np.array([START, START + 30.0]))                      # no comparison, no exception
    times.save()
    assert json.loads((tmp_path / REPLAYED_FILE).read_text()) == {"input": "run.blf", "last_time": START + 30.0}


def test_a_note_that_is_no_regular_file_is_not_read(tmp_path):
    os.symlink("/dev/zero", tmp_path / REPLAYED_FILE)
    assert InputTimes(tmp_path, "run.blf").before == {}


def test_a_fifo_in_the_state_dir_does_not_hang_the_replays_note(tmp_path):
    """The note was written through a fixed temporary name: a FIFO there blocked the replay at its end forever."""
    os.mkfifo(tmp_path / f".{REPLAYED_FILE}.partial")
    times = InputTimes(tmp_path, "run.blf")
    times.see(np.array([START]))
    saver = threading.Thread(target=times.save, daemon=True)
    saver.start()
    saver.join(timeout=60)
    assert not saver.is_alive()
    assert json.loads((tmp_path / REPLAYED_FILE).read_text())["last_time"] == START
    assert sorted(p.name for p in tmp_path.iterdir()) == [f".{REPLAYED_FILE}.partial", REPLAYED_FILE]


# ------------------------------------------------------------------------------ 3: standard output that fails
@pytest.mark.skipif(not os.path.exists("/dev/full"), reason="no /dev/full")
@pytest.mark.parametrize("command", [[*EM, "schema", "symptom"], [*EM, "deploy", "edge-monitor.env"],
                                     [*EM, "deploy", "--list"]])
def test_standard_output_on_a_full_disk_is_one_line(command):
    with open("/dev/full", "w") as full:
        done = subprocess.run(command, stdout=full, stderr=subprocess.PIPE, text=True, timeout=120)
    assert done.returncode == 1 and "Traceback" not in done.stderr and "Exception ignored" not in done.stderr
    assert "cannot write to standard output (No space left on device)" in done.stderr
    assert len(done.stderr.strip().splitlines()) == 1


@pytest.mark.skipif(not os.path.exists("/dev/full"), reason="no /dev/full")
def test_the_simulators_summary_on_a_full_disk_is_one_line(tmp_path):
    with open("/dev/full", "w") as full:
        done = subprocess.run([*SIM, "record", "--out", str(tmp_path / "r.blf"), "--joints", "1", "--cycles", "1",
                               "--json"], stdout=full, stderr=subprocess.PIPE, text=True, timeout=300)
    assert done.returncode == 1 and "Traceback" not in done.stderr
    assert "sim-controller record: cannot write to standard output" in done.stderr
    assert (tmp_path / "r.blf").stat().st_size > 0                 # the log itself is written


def test_a_reader_gone_before_the_output_is_a_quiet_end():
    """``edge-monitor schema symptom | (exit)``: the pipe is closed before the command writes."""
    proc = subprocess.Popen([*EM, "schema", "symptom"], stdout=subprocess.PIPE, stderr=subprocess.PIPE)
    proc.stdout.close()
    err = proc.stderr.read().decode()
    assert proc.wait(timeout=120) == 0 and err == ""


def test_only_failures_of_standard_output_are_taken_for_them(capsys):
    with pytest.raises(OSError) as other:
        with guarded_stdout():
            print("fine")
            raise OSError(28, "No space left on device")            # e.g. the state file, not stdout
    assert stdout_failure_exit("edge-monitor x", other.value) is None

    class Full:
        def write(self, _text: str) -> int:
            raise OSError(28, "No space left on device")

        def flush(self) -> None:
            pass

    real = sys.stdout
    sys.stdout = Full()                 # type: ignore[assignment]
    try:
        with pytest.raises(OSError) as ours:
            with guarded_stdout():
                print("lost")
    finally:
        sys.stdout = real
    assert stdout_failure_exit("edge-monitor x", ours.value) == 1
    assert "edge-monitor x: cannot write to standard output (No space left on device)" in capsys.readouterr().err


# ------------------------------------------------------------------------------ 4: the JSONL file deleted or renamed
def test_a_jsonl_file_deleted_while_open_is_made_again(tmp_path, caplog):
    """Records went on into the deleted file's inode, unreadable and lost at the agent's end, without a word."""
    path = tmp_path / "s.jsonl"
    sink = JsonlSink(path)
    sink.on_symptom(_symptom(0))
    path.unlink()
    with caplog.at_level(logging.WARNING, logger="edge_monitor.sinks.jsonl"):
        sink.on_symptom(_symptom(1))
        sink.on_symptom(_symptom(2))
    sink.close()
    assert _cycles(path) == [1, 2] and sink.failures == 0 and sink.reopens == 1
    assert "was deleted or replaced while open" in caplog.text


def test_a_jsonl_file_renamed_without_sighup_gets_a_new_path(tmp_path):
    """logrotate without its postrotate SIGHUP: the next records go to PATH, not on into the renamed file."""
    path = tmp_path / "s.jsonl"
    sink = JsonlSink(path)
    sink.on_symptom(_symptom(0))
    os.replace(path, tmp_path / "s.jsonl.1")
    sink.on_symptom(_symptom(1))
    sink.close()
    assert _cycles(tmp_path / "s.jsonl.1") == [0] and _cycles(path) == [1]


def test_a_jsonl_file_kept_in_place_is_not_reopened(tmp_path):
    path = tmp_path / "s.jsonl"
    sink = JsonlSink(path)
    for cycle in range(5):
        sink.on_symptom(_symptom(cycle))
    sink.close()
    assert sink.reopens == 0 and _cycles(path) == list(range(5))


# ------------------------------------------------------------------------------ 5: a state dir that is no directory
@pytest.mark.parametrize("make, says", [
    (lambda p: p.write_text("x"), "is a regular file, not a directory"),
    (lambda p: os.symlink(p.name, p), "is a symlink loop, not a directory"),
    (lambda p: os.symlink("/nonexistent/state", p), "is a symlink to nothing, not a directory"),
])
def test_a_state_dir_that_is_no_directory_is_named(tmp_path, make, says):
    """It said "cannot create it (File exists)"."""
    from edge_monitor.errors import StateError
    from edge_monitor.pipeline.state_store import StateStore
    path = tmp_path / "state"
    make(path)
    with pytest.raises(StateError, match=says):
        StateStore(path)


# ------------------------------------------------------------------------------ 6: a joint that can never learn
def test_a_joint_whose_cycles_give_no_friction_curve_says_so(caplog):
    """Plateaus shorter than settle_s + min_steady_s (or an agent that reads a fraction of the frames): every cycle
    skipped ("plateau cut short"), the joint "learning 0/20" for ever, and not a word in the log."""
    from edge_monitor.features.base import CycleInput
    from edge_monitor.features.friction_extraction import FrictionCurve
    from edge_monitor.features.joint_model_learning import STARVED_WARN_AT, JointModelLearner, ModelConfig
    from joint_model.friction import DEFAULT_PARAMS

    learner = JointModelLearner(ModelConfig(), DEFAULT_PARAMS, label="joint 3 model")
    empty = FrictionCurve(speeds=[], torque=[], stderr=[], skipped={"plateau cut short": 6})
    with caplog.at_level(logging.WARNING, logger="edge_monitor.features.joint_model_learning"):
        learner.update(CycleInput(joint=3, cycle=0, t=0.0, friction=empty, partial=True))    # a partial one: not counted
        for cycle in range(1, STARVED_WARN_AT[1] + 1):
            assert learner.update(CycleInput(joint=3, cycle=cycle, t=float(cycle), friction=empty)) is False
    warnings = [r.getMessage() for r in caplog.records]
    assert len(warnings) == 2 and warnings[0].startswith("joint 3 model: 5 whole cycles in a row gave no friction curve")
    assert "skipped: plateau cut short 6" in warnings[0] and "settle_s + min_steady_s" in warnings[0]
    assert warnings[1].startswith("joint 3 model: 50 whole cycles") and learner.progress.endswith(" 0/20")


def test_temporary_files_of_saves_a_kill_cut_are_removed_by_the_next_agent(tmp_path):
    """A kill -9 during a save left ``.agent_state.*.tmp`` (a whole state each) for ever: an agent restarted in a
    crash loop filled its disk."""
    from edge_monitor.pipeline.state_store import StateStore
    (tmp_path / ".agent_state.abc123.tmp").write_text('{"version": 1, "rob')
    (tmp_path / f".{REPLAYED_FILE}.x1y2.partial").write_text("{")
    os.mkfifo(tmp_path / ".agent_state.fifo.tmp")                    # not a file the agent wrote: left alone
    store = StateStore(tmp_path)
    store.claim()
    assert sorted(p.name for p in tmp_path.iterdir()) == [".agent_state.fifo.tmp", "agent_state.lock"]


def test_a_log_missing_a_run_of_frames_says_so_in_the_replay_summary(tmp_path, capsys):
    """A recording (or a link) that lost a run of frames longer than the alive counter can count (here 3 000
    frames: every joint's 8-bit counter jumps beyond max_delta) said "lost 0": the summary now names the frames
    out of sequence, and says zero of them on a whole log."""
    import can

    from edge_monitor.cli import main as edge_monitor
    from sim_controller.cli import main as sim_controller

    whole, cut = tmp_path / "whole.blf", tmp_path / "cut.blf"
    assert sim_controller(["record", "-o", str(whole), "--joints", "1", "--cycles", "3", "-q"]) == 0
    frames = list(can.LogReader(str(whole)))
    with can.Logger(str(cut)) as writer:
        for message in frames[: len(frames) // 2] + frames[len(frames) // 2 + 3000:]:
            writer.on_message_received(message)
    capsys.readouterr()
    assert edge_monitor(["replay", str(whole), "--state-dir", str(tmp_path / "a")]) == 0
    assert "out of sequence" not in capsys.readouterr().out
    assert edge_monitor(["replay", str(cut), "--state-dir", str(tmp_path / "b")]) == 0
    line = [text for text in capsys.readouterr().out.splitlines() if text.startswith("frames ")][0]
    assert "lost 0, out of sequence " in line and "cannot count" in line, line
