"""Both command-line tools follow one set of conventions (issue #14), driven through the installed
console scripts: -v/-vv/-q before or after the subcommand, documented exit codes (0, 1, 2, 130),
the subcommand's usage on bad values, python-can's -i/-c/-b and configuration chain, a final line
after --idle-stop, and progress bars on stderr only when it is a terminal."""

from __future__ import annotations

import json
import os
import pty
import re
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import can
import pytest

from protocol.links import PtyPair, open_bus

BIN = Path(sys.executable).parent
EDGE, SIM = str(BIN / "edge-monitor"), str(BIN / "sim-controller")
FAST = ["--joints", "1", "--cycles", "2", "--speeds", "20", "--plateau-time", "0.3"]
BAR = "%|"          # tqdm's bar: "record r.blf:  50%|█████     | 1/2 [00:00<00:00, 3.1cycle/s]"
NO_CAN_CONFIG = "no CAN interface configured"


def env_without_can(**extra: str) -> dict[str, str]:
    """The environment without python-can's CAN_* variables, plus ``extra``."""
    env = {k: v for k, v in os.environ.items() if not k.startswith("CAN_")}
    env.update(extra)
    return env


def cli(*cmd: str, env: dict[str, str] | None = None, cwd: Path | None = None) -> subprocess.CompletedProcess[str]:
    return subprocess.run(cmd, capture_output=True, text=True, timeout=300, env=env or env_without_can(), cwd=cwd)


def with_stderr_on_a_pty(*cmd: str) -> tuple[int, str, str]:
    """Run ``cmd`` with stderr on a pseudo-terminal (as in a shell), stdout on a pipe: (code, stdout, stderr)."""
    master, slave = pty.openpty()
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=slave, env=env_without_can())
    os.close(slave)
    chunks: list[bytes] = []

    def drain() -> None:            # until the child's end closes (EIO): it never blocks on a full pty
        while True:
            try:
                data = os.read(master, 65536)
            except OSError:
                return
            if not data:
                return
            chunks.append(data)

    reader = threading.Thread(target=drain, daemon=True)
    reader.start()
    try:
        out, _ = proc.communicate(timeout=300)
        reader.join(timeout=60)
    finally:
        os.close(master)
    return proc.returncode, out.decode(), b"".join(chunks).decode(errors="replace")


def agent_config(tmp_path: Path) -> str:
    path = tmp_path / "agent.toml"
    path.write_text("status_interval_s = 0.1\n")
    return str(path)


@pytest.fixture(scope="module")
def recorded_log(tmp_path_factory: pytest.TempPathFactory) -> Path:
    log = tmp_path_factory.mktemp("log") / "run.blf"
    done = cli(SIM, "record", "--out", str(log), *FAST, "-q")
    assert done.returncode == 0, done.stderr
    return log


# --- 1. verbosity: one helper, before or after the subcommand ---------------------------------------

@pytest.mark.parametrize("before, after, info, summary", [
    (["-v"], [], True, True),
    ([], ["-v"], True, True),
    ([], [], False, True),
    ([], ["-q"], False, False),
])
def test_sim_controller_verbosity_before_or_after_the_subcommand(tmp_path, before, after, info, summary):
    done = cli(SIM, *before, "record", "--out", str(tmp_path / "r.blf"), *FAST, *after)
    assert done.returncode == 0, done.stderr
    assert ("INFO sim_controller: record: 1 joints, 2 cycles" in done.stderr) == info, done.stderr
    assert ("sim-controller record: " in done.stderr and "real time)" in done.stderr) == summary, done.stderr
    if not summary:
        assert done.stderr == ""


@pytest.mark.slow
@pytest.mark.parametrize("before, after, status", [
    ([], [], False),
    (["-v"], [], True),
    ([], ["-v"], True),
    (["-q"], [], False),
])
def test_edge_monitor_status_line_only_with_v_before_or_after(tmp_path, before, after, status):
    done = cli(EDGE, *before, "run", "--link", f"virtual:{tmp_path.name}", "--no-zenoh", "--pf", "0.01",
               "--config", agent_config(tmp_path), "--duration", "0.3", *after)
    assert done.returncode == 0, done.stderr
    assert ("INFO edge_monitor.status: status: " in done.stderr) == status, done.stderr
    final = "edge-monitor run: stopped: --duration 0.3 s reached; 0 frames"
    if before == ["-q"]:
        assert done.stderr == ""
    else:
        assert final in done.stderr


# --- 2. exit codes, documented in --help ------------------------------------------------------------

@pytest.mark.parametrize("cmd", [[EDGE, "--help"], [SIM, "--help"], [EDGE, "replay", "--help"],
                                 [SIM, "run", "--help"]])
def test_help_documents_the_exit_codes(cmd):
    done = cli(*cmd)
    assert done.returncode == 0, done.stderr
    text = " ".join(done.stdout.split())
    assert "exit codes: 0 ok; 1 runtime failure" in text and "2 usage error" in text and "130 interrupted" in text
    assert "-v, --verbose" in text and "-q, --quiet" in text


def test_runtime_failures_exit_1_in_both_tools(tmp_path, recorded_log):
    missing = tmp_path / "no-such-tty"
    cases = [
        ([SIM, "run", "--link", f"slcan:{missing}", *FAST], f"slcan:{missing}: device not found"),
        ([EDGE, "run", "--link", f"slcan:{missing}", "--no-zenoh", "--pf", "0.01"], f"slcan:{missing}: device not found"),
        ([SIM, "record", "--out", str(tmp_path / "nodir" / "x.blf"), *FAST], "cannot write log"),
        ([EDGE, "replay", str(tmp_path / "missing.blf")], "not found"),
    ]
    for cmd, message in cases:
        done = cli(*cmd)
        assert done.returncode == 1 and message in done.stderr and "Traceback" not in done.stderr, (cmd, done.stderr)


# --- 3. bad values: the subcommand's usage, exit code 2 ---------------------------------------------

@pytest.mark.parametrize("cmd, usage, message", [
    ([SIM, "record", "--out", "x.blf", "--joints", "9"], "usage: sim-controller record", "joints: must be an integer 1 … 8"),
    ([SIM, "run", "--link", "x.blf", *FAST], "usage: sim-controller run", "is a log file"),
    ([EDGE, "demo", "--joints", "9"], "usage: edge-monitor demo", "1 <= --joints <= 8"),
    ([EDGE, "glr", "--nominal", "a.csv", "--test", "b.csv", "--pf", "1.5"], "usage: edge-monitor glr", "between 0 and 1"),
])
def test_bad_values_print_the_subcommands_usage(tmp_path, cmd, usage, message):
    done = cli(*cmd, cwd=tmp_path)
    assert done.returncode == 2, done.stderr
    assert done.stderr.startswith(usage) and message in done.stderr, done.stderr
    assert not (tmp_path / "x.blf").exists()


# --- 4. python-can's -i/-c/-b and configuration chain ------------------------------------------------

@pytest.mark.parametrize("options, env, canrc", [
    (["-i", "virtual", "-c", "conventions", "-b", "500000"], {}, False),
    ([], {"CAN_INTERFACE": "virtual", "CAN_CHANNEL": "from-env"}, False),
    ([], {}, True),
])
def test_sim_run_takes_python_can_options_and_configuration(tmp_path, options, env, canrc):
    if canrc:
        (tmp_path / ".canrc").write_text("[default]\ninterface = virtual\nchannel = from-canrc\n")
    done = cli(SIM, "run", *options, *FAST, "--speedup", "0", "--json",
               env=env_without_can(HOME=str(tmp_path), **env), cwd=tmp_path)
    assert done.returncode == 0, done.stderr
    assert json.loads(done.stdout)["frames_sent"] > 0


@pytest.mark.skipif(Path("/etc/can.conf").exists(), reason="this machine has a system-wide python-can config")
@pytest.mark.parametrize("cmd", [[SIM, "run", *FAST], [EDGE, "run", "--no-zenoh", "--pf", "0.01"]])
def test_no_can_configuration_says_what_to_do(tmp_path, cmd):
    done = cli(*cmd, env=env_without_can(HOME=str(tmp_path)), cwd=tmp_path)
    assert done.returncode == 2, done.stderr
    assert NO_CAN_CONFIG in done.stderr and "--link" in done.stderr and "~/.canrc" in done.stderr
    assert "Unknown interface type" not in done.stderr and "Traceback" not in done.stderr


# --- 2 (cont.). Ctrl-C exits with 130 ---------------------------------------------------------------
# A FIFO tells when the command is at work: opening one end returns once the command opened the other.

def interruptible() -> None:
    """Ctrl-C reaches the child even when this suite runs in a background job (a non-interactive shell
    starts background jobs with SIGINT ignored, and the child would inherit that)."""
    signal.signal(signal.SIGINT, signal.SIG_DFL)


def test_ctrl_c_during_sim_record_exits_130(tmp_path):
    fifo = tmp_path / "live.log"
    os.mkfifo(fifo)
    proc = subprocess.Popen([SIM, "record", "--out", str(fifo), "--joints", "1", "--cycles", "1000"],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=env_without_can(),
                            preexec_fn=interruptible)
    try:
        with open(fifo, "rb") as reader:
            assert reader.read(1)          # writing; it blocks on the full pipe until read
            proc.send_signal(signal.SIGINT)
            reader.read()                  # what it flushes on the way out, up to its close
        _, err = proc.communicate(timeout=120)
    finally:
        if proc.poll() is None:
            proc.kill()
    assert proc.returncode == 130, err
    assert "sim-controller record: interrupted" in err and "Traceback" not in err


def test_ctrl_c_during_edge_replay_exits_130(tmp_path):
    """replay reads only regular files (a FIFO would block it): a long recording, interrupted once the
    agent has seen its first joint (its INFO line with -v)."""
    log = tmp_path / "long.blf"
    subprocess.run([SIM, "record", "--out", str(log), "--joints", "1", "--cycles", "60"], check=True,
                   capture_output=True, env=env_without_can(), timeout=600)
    proc = subprocess.Popen([EDGE, "-v", "replay", str(log)], stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                            text=True, env=env_without_can(), preexec_fn=interruptible)
    try:
        seen = []
        for line in proc.stderr:               # at work: the first frames reached the agent
            seen.append(line)
            if "monitoring started" in line:
                break
        proc.send_signal(signal.SIGINT)
        _, err = proc.communicate(timeout=120)
    finally:
        if proc.poll() is None:
            proc.kill()
    err = "".join(seen) + err
    assert proc.returncode == 130, err[-3000:]
    assert "edge-monitor replay: interrupted" in err and "Traceback" not in err


# --- 5. --idle-stop ends with a line saying so ---------------------------------------------------------

@pytest.mark.slow
def test_idle_stop_says_why_the_agent_stopped(tmp_path):
    lines: list[str] = []
    with PtyPair() as pair:
        agent = subprocess.Popen([EDGE, "run", "--link", f"slcan:{pair.b}", "--no-zenoh", "--pf", "0.01",
                                  "--config", agent_config(tmp_path), "--idle-stop", "1", "-v"],
                                 stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, env=env_without_can())
        reader = threading.Thread(target=lambda: lines.extend(agent.stdout or ()), daemon=True)
        reader.start()
        received = re.compile(r"status: [1-9]\d* frames")
        sender = open_bus(f"slcan:{pair.a}")
        try:   # frames until the agent's status line counts some (its end of the link is open by then)
            deadline = time.monotonic() + 120
            while not any(received.search(x) for x in list(lines)) and agent.poll() is None \
                    and time.monotonic() < deadline:
                sender.send(can.Message(arbitration_id=0x123, data=bytes(8), is_extended_id=False))
                time.sleep(0.05)
        finally:
            sender.shutdown()
        try:
            agent.wait(timeout=120)
        finally:
            if agent.poll() is None:
                agent.kill()
        reader.join(timeout=30)
    out = "".join(lines)
    assert agent.returncode == 0, out
    assert "edge-monitor run: stopped: the bus was idle for 1 s (--idle-stop);" in out, out


# --- 6. progress bars: on a terminal only, never on stdout, off with -q --------------------------------

def _record(tmp_path: Path) -> list[str]:
    return [SIM, "record", "--out", str(tmp_path / "r.blf"), *FAST]


def _replay(log: Path) -> list[str]:
    return [EDGE, "replay", str(log), "--json"]


@pytest.mark.parametrize("tool", ["record", "replay"])
def test_progress_bar_on_a_terminal_only(tmp_path, recorded_log, tool):
    cmd, unit = (_record(tmp_path), "cycle/s") if tool == "record" else (_replay(recorded_log), "B/s")
    code, out, err = with_stderr_on_a_pty(*cmd)
    assert code == 0, err
    assert BAR in err and unit in err, err
    assert BAR not in out
    if tool == "replay":
        assert json.loads(out)["frames_total"] > 0           # stdout stays parseable

    code, out, err = with_stderr_on_a_pty(*cmd, "-q")
    assert code == 0 and BAR not in err, err

    piped = cli(*cmd)
    assert piped.returncode == 0, piped.stderr
    assert BAR not in piped.stderr and BAR not in piped.stdout and unit not in piped.stderr
