"""The live agent's calibration worker ends with its parent: a pool worker waits for work for ever, so
before ``exit_with_parent`` an agent killed with SIGKILL left it behind (found 2026-11-30: alive 20 s
later and on, ≈ 130 MB)."""

from __future__ import annotations

import signal
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]

SCRIPT = textwrap.dedent("""
    import os, sys, time, types
    sys.path.insert(0, {root!r})
    from edge_monitor.stats.calibrators import ProcessCalibrator

    if __name__ == "__main__":
        calibrator = ProcessCalibrator()      # kept: a pool dropped ends its workers itself
        pending = calibrator.submit(types.SimpleNamespace(run=os.getpid))   # the worker's pid
        while (pid := pending.result()) is None:
            time.sleep(0.05)
        print(pid, flush=True)
        time.sleep(600)
""")


def _gone(pid: int) -> bool:
    """No such process, or a zombie (a container's init may not reap it)."""
    try:
        stat = Path(f"/proc/{pid}/stat").read_text()
    except OSError:
        return True
    return stat.rsplit(")", 1)[1].split()[0] == "Z"


@pytest.mark.skipif(not Path("/proc").is_dir(), reason="needs /proc to see the worker")
def test_the_calibration_worker_ends_when_its_agent_is_killed(tmp_path: Path):
    script = tmp_path / "agent_like.py"
    script.write_text(SCRIPT.format(root=str(ROOT)))
    parent = subprocess.Popen([sys.executable, str(script)], stdout=subprocess.PIPE, text=True)
    try:
        worker = int(parent.stdout.readline())
        assert worker != parent.pid and not _gone(worker)
        parent.send_signal(signal.SIGKILL)
        parent.wait(timeout=30)
        deadline = time.monotonic() + 60
        while not _gone(worker) and time.monotonic() < deadline:
            time.sleep(0.1)
        assert _gone(worker), "the calibration worker outlived its killed parent"
    finally:
        if parent.poll() is None:
            parent.kill()
