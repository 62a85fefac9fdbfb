"""SIGTERM takes Ctrl-C's path in both command-line tools: workers stopped, outputs closed, a message and
exit code 143, instead of Python's default death that leaves a replay's monitoring process and its
semaphores behind (found 2026-11-30: "the replay process is gone", "6 leaked semaphore objects")."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import can
import pytest

import edge_monitor.cli
from protocol.console import (
    EXIT_TERMINATED,
    Terminated,
    deferred_interrupts,
    interrupted_exit,
    terminate_like_interrupt,
)


def test_sigterm_raises_terminated_in_the_main_thread_and_the_handler_is_restored():
    previous = signal.getsignal(signal.SIGTERM)
    with pytest.raises(Terminated), terminate_like_interrupt():
        os.kill(os.getpid(), signal.SIGTERM)
        time.sleep(5)           # the handler runs at the next bytecode; never reached
    assert signal.getsignal(signal.SIGTERM) is previous


def test_deferred_interrupts_note_the_signal_and_raise_nothing():
    previous = signal.getsignal(signal.SIGINT), signal.getsignal(signal.SIGTERM)
    with deferred_interrupts() as interrupt:
        assert interrupt.pending is None
        os.kill(os.getpid(), signal.SIGTERM)
        time.sleep(0.01)
        assert isinstance(interrupt.pending, Terminated)
        os.kill(os.getpid(), signal.SIGINT)
        time.sleep(0.01)
        assert type(interrupt.pending) is KeyboardInterrupt
    assert (signal.getsignal(signal.SIGINT), signal.getsignal(signal.SIGTERM)) == previous


def test_interrupted_exit_tells_a_termination_from_ctrl_c(capsys):
    assert interrupted_exit("tool cmd", Terminated("signal 15")) == EXIT_TERMINATED == 143
    assert interrupted_exit("tool cmd", KeyboardInterrupt()) == 130
    err = capsys.readouterr().err
    assert "tool cmd: terminated (SIGTERM)" in err and "tool cmd: interrupted" in err


def test_edge_monitor_command_terminated_by_sigterm(monkeypatch, capsys):
    """A subcommand that gets SIGTERM mid-work: the CLI says so and exits 143 (no traceback)."""
    import edge_monitor.commands.schema as schema_command

    def work(_args):
        os.kill(os.getpid(), signal.SIGTERM)
        time.sleep(5)
        return 0
    previous = signal.getsignal(signal.SIGTERM)
    monkeypatch.setattr(schema_command, "main", work, raising=False)
    parser_func = edge_monitor.cli.build_parser("schema")
    args = parser_func.parse_args(["schema", "symptom"])
    monkeypatch.setattr(edge_monitor.cli, "build_parser", lambda only=None: _Fixed(args, work))
    try:
        assert edge_monitor.cli.main(["schema", "symptom"]) == 143
    finally:
        signal.signal(signal.SIGTERM, previous)
    assert "edge-monitor schema: terminated (SIGTERM)" in capsys.readouterr().err


class _Fixed:
    """A parser stand-in that returns fixed arguments whose subcommand function is ``func``."""

    def __init__(self, args, func):
        self.args, self.func = args, func

    def parse_args(self, _argv):
        self.args.func = self.func
        return self.args


@pytest.mark.parametrize("signum, code, said", [(signal.SIGTERM, 143, "terminated (SIGTERM)"),
                                                (signal.SIGINT, 130, "interrupted")])
def test_sim_controller_record_stopped_leaves_a_readable_log(tmp_path: Path, signum, code, said):
    """A real process: ``sim-controller record`` of a long run, stopped once frames are on disk. The log is
    closed after a whole block (python-can reads it to its end: before, a BLF cut mid-container raised
    BLFParseError), the message and exit code say what happened."""
    log = tmp_path / "cut.blf"
    proc = subprocess.Popen([sys.executable, "-m", "sim_controller.cli", "record", "--cycles", "100000",
                             "--joints", "1", "--out", str(log)], stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                            text=True, env={**os.environ, "PYTHONWARNINGS": "default"})
    deadline = time.monotonic() + 300
    while (not log.exists() or log.stat().st_size < 200_000) and proc.poll() is None:
        assert time.monotonic() < deadline, "no frames written in 300 s"
        time.sleep(0.2)
    assert proc.poll() is None, proc.communicate()
    proc.send_signal(signum)
    out, err = proc.communicate(timeout=120)
    assert proc.returncode == code, err
    assert f"sim-controller record: {said}" in err and "the log is readable up to there" in err
    assert "Traceback" not in err and "leaked" not in err
    frames = sum(1 for _ in can.LogReader(str(log)))
    assert frames > 0


@pytest.mark.slow
def test_demo_stopped_by_sigterm_stops_the_simulator_and_still_summarises(tmp_path: Path):
    """The demo, a real process with its simulator, agent and Zenoh: SIGTERM once symptoms flow. It stops
    the simulator, writes its summary of what was seen, says so and exits 143."""
    out = tmp_path / "demo"
    proc = subprocess.Popen([sys.executable, "-m", "edge_monitor.cli", "demo", "--cycles", "100000", "--joints", "1",
                             "--nominal-cycles", "10", "--out", str(out), "--rerun", "off", "-q"],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    symptoms = out / "symptoms.jsonl"
    deadline = time.monotonic() + 300
    while (not symptoms.exists() or symptoms.stat().st_size == 0) and proc.poll() is None:
        assert time.monotonic() < deadline, "no symptom written in 300 s"
        time.sleep(0.2)
    assert proc.poll() is None, proc.communicate()
    proc.send_signal(signal.SIGTERM)
    _, err = proc.communicate(timeout=180)
    assert proc.returncode == EXIT_TERMINATED, err
    assert "edge-monitor demo: terminated (SIGTERM)" in err and "Traceback" not in err
    summary = (out / "summary.json").read_text()
    assert '"simulator_exit_code"' in summary


def _interruptible() -> None:
    """Ctrl-C reaches the replay even when this suite runs in a background job: a non-interactive shell starts
    those with SIGINT ignored, Python then keeps it ignored, and the replay rightly ran on (exit 0; a clean-clone
    CI started in the background, 2026-11-30)."""
    signal.signal(signal.SIGINT, signal.SIG_DFL)


#: Attempts at landing the signal mid-log: a test process starved on a loaded machine can read the replay's
#: first lines so late that it has already finished (exit 0, its summary printed); such an attempt says nothing.
ATTEMPTS = 3


def _interrupt(log: Path, jsonl: Path, signum: int, to_group: bool) -> tuple[int | None, str, str]:
    """One ``replay --jobs 2`` of ``log`` sent ``signum`` once its monitoring process is at work: (exit code,
    stdout, stderr)."""
    proc = subprocess.Popen([sys.executable, "-m", "edge_monitor.cli", "-v", "replay", str(log), "--jobs", "2",
                             "--rerun", "off", "--jsonl", str(jsonl)], stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True, start_new_session=True, preexec_fn=_interruptible)
    try:
        seen = []
        assert proc.stderr is not None
        for line in proc.stderr:                 # at work: the child has its first joint
            seen.append(line)
            if "monitoring started" in line:
                break
        # held while the signal is sent, so that it lands mid-log unless the replay is already done; it is
        # delivered on SIGCONT
        os.killpg(proc.pid, signal.SIGSTOP)
        if proc.poll() is None:
            if to_group:
                os.killpg(proc.pid, signum)
            else:
                proc.send_signal(signum)
            os.killpg(proc.pid, signal.SIGCONT)
        out, err = proc.communicate(timeout=60)
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
    return proc.returncode, out, "".join(seen) + err


@pytest.mark.slow
@pytest.mark.parametrize("signum, to_group, code", [(signal.SIGINT, True, 130), (signal.SIGTERM, False, 143)])
def test_replay_with_two_processes_stops_on_ctrl_c_and_sigterm(tmp_path: Path, signum, to_group, code):
    """``replay --jobs 2`` stopped mid-log: Ctrl-C in a terminal reaches the whole process group, SIGTERM
    from a supervisor only the main process. Either way it exits with its code, the monitoring process is
    gone and the symptoms written are whole lines. Before, the main process hung at exit for ever: its queue
    waited to hand blocks to a child that was gone (found 2026-11-30). An attempt the replay finished before the
    signal landed (exit 0; a clean-clone CI, 2026-12-01) is tried again, at most :data:`ATTEMPTS` times: a replay
    that ignored the signal mid-log would finish every time."""
    log = tmp_path / "long.blf"
    subprocess.run([sys.executable, "-m", "sim_controller.cli", "record", "--out", str(log), "--joints", "2",
                    "--cycles", "200"], check=True, capture_output=True, timeout=600)
    jsonl = tmp_path / "s.jsonl"
    for _ in range(ATTEMPTS):
        jsonl.unlink(missing_ok=True)
        returncode, _, err = _interrupt(log, jsonl, signum, to_group)
        if returncode != 0:
            break
    assert returncode == code, err[-3000:]
    assert "Traceback" not in err
    for line in jsonl.read_text().splitlines():
        json.loads(line)
