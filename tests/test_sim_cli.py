"""``sim-controller`` as a user runs it: record/run, scenario files, bad input, a real pty slcan link."""

from __future__ import annotations

import json
import signal
import subprocess
import sys
import time
from contextlib import contextmanager
from pathlib import Path
from typing import Iterator

import can
import numpy as np
import pytest

from protocol import frames as pf
from protocol.links import PtyPair, open_bus
from sim_controller.cli import main

SIM = [sys.executable, "-m", "sim_controller.cli"]
FAST = ["--joints", "2", "--cycles", "2", "--speeds", "10,100", "--plateau-time", "0.3"]


def read_truth(path: Path) -> tuple[list[dict], dict]:
    lines = [json.loads(s) for s in path.read_text().splitlines()]
    return lines[:-1], lines[-1]


def test_record_cli_writes_log_and_truth(tmp_path, capsys):
    out, truth = tmp_path / "run.blf", tmp_path / "truth.jsonl"
    code = main(["record", "--out", str(out), "--truth", str(truth), "--seed", "4", "--json",
                 "--wear-ramp", "all:0:1:0:30", "--temperature-range", "35:45", *FAST])
    assert code == 0
    summary = json.loads(capsys.readouterr().out)
    records, last = read_truth(truth)
    assert summary["frames_sent"] == last["frames_sent"] == sum(1 for _ in can.LogReader(out))
    assert [r["wear"] for r in records] == [0.0, 0.0, 30.0, 30.0]
    assert all(35.0 <= r["temperature"] <= 45.0 for r in records)


def test_scenario_file_and_speeds_from_design_json(tmp_path):
    scenario = tmp_path / "s.toml"
    scenario.write_text("""
[simulation]
joints = 2
cycles = 4
plateau_time = 0.3
seed = 3
load_range = [0.5, 0.5]

[faults]
drop = 0.001

[[joint]]
index = 1
wear_initial = 10
friction = { fc0 = 0.04 }
wear = [ { kind = "step", start = 1, to = 25 }, { kind = "replacement", start = 3 } ]
""")
    design = tmp_path / "design.json"
    design.write_text(json.dumps({"speeds": [12.5, 60.0], "wear_crlb": 1.0}))
    truth = tmp_path / "t.jsonl"
    assert main(["record", "--out", str(tmp_path / "s.log"), "--scenario", str(scenario),
                 "--speeds-from", str(design), "--truth", str(truth), "--cycles", "4"]) == 0
    records, last = read_truth(truth)
    joint1 = [r for r in records if r["joint"] == 1]
    assert [r["wear"] for r in joint1] == [10.0, 25.0, 25.0, 0.0]
    assert [r["maintenance"] for r in joint1] == [False, False, False, True]
    assert all(r["speeds"] == [12.5, 60.0] and abs(r["load"]) == 0.5 for r in records)
    assert last["faults"]["dropped"] > 0
    params = json.loads((tmp_path / "t.params.json").read_text())
    assert params["joints"][1]["friction"]["fc0"] == 0.04


@pytest.mark.parametrize("args, message", [
    (["--joints", "9"], "joints: must be an integer 1 … 8"),
    (["--joints", "two"], "joints: expected an integer"),
    (["--rate", "-500"], "rate: must be 50 … 5000 Hz"),
    (["--cycles", "0"], "cycles: must be an integer ≥ 1"),
    (["--temperature-range", "60:40"], "temperature_range: LOW must be ≤ HIGH"),
    (["--temperature-range", "40"], "temperature_range: expected LOW:HIGH"),
    (["--wear-ramp", "6:0:10:0:50"], "wear_ramp: unknown joint 6"),
    (["--wear-ramp", "0:0:10:0:150"], "wear must be 0 … 100"),
    (["--wear-ramp", "0:10:5:0:50"], "end: must be ≥ start"),
    (["--wear-ramp", "x:0:10:0:50"], "JOINT must be an integer or 'all'"),
    (["--speeds", "10,-3"], "speeds: each speed must be in"),
    (["--faults", "drop=-0.1"], "faults.drop: probability must be 0 … 1"),
    (["--friction-model-error", "-1"], "friction_model_error: must be 0 … 0.1"),
    (["--load-range", "0.5:1.5"], "load_range: need 0 ≤ LOW ≤ HIGH ≤ 1"),
])
def test_bad_input_is_refused_naming_the_field(tmp_path, capsys, args, message):
    with pytest.raises(SystemExit) as exit_info:
        main(["record", "--out", str(tmp_path / "x.blf"), *args])
    assert exit_info.value.code == 2
    assert message in capsys.readouterr().err
    assert not (tmp_path / "x.blf").exists()


def test_bad_scenario_file_names_the_field(tmp_path, capsys):
    cases = {
        "[simulation]\nrate = -1\n": "rate: must be 50 … 5000 Hz",
        "[simulation]\nratee = 500\n": "scenario.simulation.ratee: unknown field",
        "[[joint]]\nindex = 7\n": "scenario.joint[0].index: unknown joint 7",
        "[[joint]]\nindex = 0\nwear = [{kind = \"ramp\", start = 1}]\n": "scenario.joint[0].wear[0]: wear.ramp.end: required",
        "[[joint]]\nindex = 0\nfriction = { alpha = -1 }\n": "scenario.joint[0].friction.alpha: must be > 0",
        "[[joint]]\nindex = 0\nwear = [{kind = \"melt\", start = 1}]\n": "scenario.joint[0].wear[0].kind",
        "[simulation\n": "is not valid TOML",
    }
    for n, (text, message) in enumerate(cases.items()):
        path = tmp_path / f"s{n}.toml"
        path.write_text(text)
        with pytest.raises(SystemExit) as exit_info:
            main(["record", "--out", str(tmp_path / "x.log"), "--scenario", str(path)])
        assert exit_info.value.code == 2
        assert message in capsys.readouterr().err, text


@pytest.mark.slow   # a fresh interpreter importing numpy/scipy/python-can: ~2–5 s on a busy machine
def test_unopenable_link_says_which_and_why(tmp_path):
    missing = tmp_path / "no-such-tty"
    result = subprocess.run([*SIM, "run", "--link", f"slcan:{missing}", *FAST], capture_output=True, text=True,
                            timeout=120)
    assert result.returncode == 1
    assert f"slcan:{missing}: device not found" in result.stderr


def test_unwritable_output_says_which_and_why(tmp_path, capsys):
    assert main(["record", "--out", str(tmp_path / "nodir" / "x.blf"), *FAST]) == 1
    assert "nodir/x.blf: cannot write log" in capsys.readouterr().err
    with pytest.raises(SystemExit) as exited:       # a file name no log format has: a usage error
        main(["record", "--out", str(tmp_path / "x.txt"), *FAST])
    assert exited.value.code == 2 and "not a CAN log file" in capsys.readouterr().err


@pytest.mark.parametrize("truth", ["folder", "nodir/truth.jsonl", "file/truth.jsonl", f"{'a' * 300}/t.jsonl"])
@pytest.mark.parametrize("command", ["record", "run"])
def test_a_truth_path_that_cannot_be_a_file_is_a_usage_error_before_anything_runs(tmp_path, capsys, command, truth):
    """--truth naming a folder, or a path in a missing folder, printed "[Errno 21] Is a directory: …" / "[Errno 2]
    No such file or directory: …" (exit 1) after the log --out was created; now the subcommand's usage and one
    line saying what is wrong with --truth, exit 2, before anything is simulated or written."""
    (tmp_path / "folder").mkdir()
    (tmp_path / "file").write_text("")
    out = tmp_path / "x.blf"
    where = ["--out", str(out)] if command == "record" else ["--link", "virtual:truth-check"]
    with pytest.raises(SystemExit) as exited:
        main([command, *where, "--truth", str(tmp_path / truth), *FAST])
    err = capsys.readouterr().err
    says = {"folder": f"--truth {tmp_path / 'folder'}: is a directory; give a file name",
            "nodir/truth.jsonl": f"its folder {tmp_path / 'nodir'} does not exist: create it",
            "file/truth.jsonl": f"{tmp_path / 'file'} is a file, not a folder"}.get(
                truth, "cannot be checked (File name too long): fix the path")       # stat fails (ENAMETOOLONG)
    assert exited.value.code == 2 and f"sim-controller {command}: error: " in err and says in err, err
    assert "Errno" not in err and not out.exists()
    assert main(["record", "--out", str(out), "--truth", str(tmp_path / "folder" / "t.jsonl"), *FAST]) == 0
    assert (tmp_path / "folder" / "t.jsonl").stat().st_size > 0 and out.exists()


@contextmanager
def _sim_run_over_pty(*args: str) -> Iterator[tuple[PtyPair, can.BusABC, subprocess.Popen]]:
    """`sim-controller run` of one joint at 20 rad/s (plus ``args``) into one end of a pty pair, a
    python-can slcan receiver on the other; the receiver is shut down on the way out."""
    with PtyPair() as pty:
        receiver = open_bus(f"slcan:{pty.b}")
        try:
            proc = subprocess.Popen([*SIM, "run", "--link", f"slcan:{pty.a}", "--joints", "1", "--speeds", "20",
                                     "--plateau-time", "0.3", *args],
                                    stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
            yield pty, receiver, proc
        finally:
            receiver.shutdown()


@pytest.mark.slow
def test_cross_process_run_over_pty_slcan_reaches_a_python_can_receiver(tmp_path):
    truth = tmp_path / "truth.jsonl"
    with _sim_run_over_pty("--speedup", "20", "--cycles", "1", "--truth", str(truth), "--seed", "5") \
            as (pty, receiver, proc):
        messages = []
        deadline = time.monotonic() + 120
        while time.monotonic() < deadline:
            msg = receiver.recv(timeout=0.5)
            if msg is not None:
                messages.append(msg)
            elif proc.poll() is not None:
                break
        _, stderr = proc.communicate(timeout=30)
        assert proc.returncode == 0, stderr
        assert pty.dropped_bytes == 0
    _, last = read_truth(truth)
    assert len(messages) == last["frames_sent"] > 1000
    ids, data, dlc, _ = pf.messages_to_arrays(messages)
    decoded = pf.decode_block(ids, data, dlc)
    assert decoded.valid.all()
    motor = decoded.kind == pf.FrameKind.MOTOR_STATE
    assert np.array_equal(decoded.counter[motor], np.arange(motor.sum()) % 256)
    assert np.any(np.abs(decoded.speed[motor] - 20.0) < 0.1)
    assert all(not m.is_extended_id for m in messages)


def test_sigterm_ends_a_run_in_order_with_every_sent_frame_in_the_truth_summary(tmp_path):
    truth = tmp_path / "truth.jsonl"
    with _sim_run_over_pty("--speedup", "1", "--cycles", "1000", "--truth", str(truth), "--summary-json") \
            as (_, receiver, proc):
        received = 0
        deadline = time.monotonic() + 120
        while received < 1000 and time.monotonic() < deadline:     # streaming: then stop it
            received += receiver.recv(timeout=0.5) is not None
        proc.send_signal(signal.SIGTERM)
        while time.monotonic() < deadline:
            if receiver.recv(timeout=0.5) is not None:
                received += 1
            elif proc.poll() is not None:
                break
        out, err = proc.communicate(timeout=30)
    assert proc.returncode == 0, err
    _, last = read_truth(truth)
    assert last["frames_sent"] == json.loads(out)["frames_sent"] == received >= 1000
    assert last["send_errors"] == json.loads(out)["send_errors"] == 0


def test_run_on_virtual_bus_in_process_paced_by_speedup():
    from test_sim_support import run_on_virtual_bus

    from sim_controller.config import SimConfig
    config = SimConfig(joints=1, cycles=1, speeds=(20.0,), plateau_time=0.2, seed=1)
    summary, received = run_on_virtual_bus(config, "sim-test-run", speedup=None)
    assert received == summary.frames_sent > 0 and summary.send_errors == 0


def test_help_lists_the_options(capsys):
    with pytest.raises(SystemExit) as exit_info:
        main(["record", "--help"])
    assert exit_info.value.code == 0
    out = capsys.readouterr().out
    assert "--friction-model-error" in out and "--scenario" in out and "--truth" in out


def test_scenario_all_joints_follows_the_command_line_joint_count(tmp_path):
    scenario = tmp_path / "all.toml"
    scenario.write_text('[simulation]\njoints = 2\n\n[[joint]]\nindex = "all"\nwear_initial = 12\n')
    truth = tmp_path / "t.jsonl"
    assert main(["record", "--out", str(tmp_path / "a.log"), "--scenario", str(scenario), "--joints", "3",
                 "--truth", str(truth), "--cycles", "1", "--speeds", "20", "--plateau-time", "0.3"]) == 0
    records, _ = read_truth(truth)
    assert [(r["joint"], r["wear"]) for r in records] == [(0, 12.0), (1, 12.0), (2, 12.0)]
