"""Storage that fails, as on an edge box on a normal day (issue 28): a full disk under the JSONL file
and the state, a state file or output path that is not a file. The real commands run as a user runs
them; a write that fails comes from the kernel (RLIMIT_FSIZE: EFBIG, and a real ENOSPC on a small
tmpfs where the test may mount one)."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import pytest
from hostile_files import edge_monitor, run_measured

from edge_monitor.pipeline.state_store import STATE_FILE
from sim_controller.config import SimConfig
from sim_controller.output import record


@pytest.fixture(scope="module")
def recording(tmp_path_factory) -> Path:
    """2 joints, 3 cycles (≈ 40,000 frames)."""
    path = tmp_path_factory.mktemp("rec") / "run.blf"
    record(SimConfig(joints=2, cycles=3, seed=5), path)
    return path


def _whole_lines(path: Path) -> list[dict]:
    data = path.read_bytes()
    assert not data or data.endswith(b"\n"), "a torn last line"
    return [json.loads(line) for line in data.splitlines()]


def test_replay_on_a_full_disk_keeps_whole_records_counts_the_rest_and_exits_1(recording, tmp_path):
    """The disk fills after a few records (writes past 12 kB fail): the JSONL keeps its complete
    records, the others are counted in sink_errors, the state save fails without a traceback and the
    previous state (none) is kept; the statistics are still printed, the exit code is 1."""
    jsonl, state = tmp_path / "s.jsonl", tmp_path / "state"
    run = run_measured(edge_monitor("replay", str(recording), "--json", "--jsonl", str(jsonl),
                                    "--state-dir", str(state)), file_size_limit=12_000, timeout=600)
    assert run.returncode == 1 and "Traceback" not in run.stderr, run.stderr[-3000:]
    stats = json.loads(run.stdout)
    written = _whole_lines(jsonl)
    assert 0 < len(written) < stats["symptoms"]
    assert stats["details"]["sink_errors"] == stats["symptoms"] - len(written)
    assert "could not be written" in run.stderr and "the last state save failed" in run.stderr
    assert not (state / STATE_FILE).exists() and not list(state.glob(".agent_state.*"))   # no temp file left


def test_run_stopped_by_sigterm_on_a_full_disk_says_so_and_exits_1(tmp_path):
    """The final state save at SIGTERM fails (no byte may be written): one clear line, exit code 1."""
    config = tmp_path / "agent.toml"
    config.write_text("status_interval_s = 0.2\n")
    state = tmp_path / "state"
    proc = subprocess.Popen(edge_monitor("-v", "run", "--link", "virtual:full-disk", "--no-zenoh", "--config",
                                         str(config), "--state-dir", str(state)),
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            preexec_fn=lambda: _limit_file_size(0))
    lines: list[str] = []
    reader = threading.Thread(target=lambda: lines.extend(proc.stderr), daemon=True)
    reader.start()
    try:
        deadline = time.monotonic() + 300
        while not any("status:" in line for line in list(lines)) and time.monotonic() < deadline:
            time.sleep(0.1)
        assert any("status:" in line for line in list(lines)), "".join(lines)[-2000:]
        proc.send_signal(signal.SIGTERM)
        assert proc.wait(timeout=120) == 1
    finally:
        proc.kill()
    reader.join(timeout=10)
    text = "".join(lines)
    assert "the last state save failed" in text and "Traceback" not in text, text[-3000:]
    assert not (state / STATE_FILE).exists() and not list(state.glob(".agent_state.*"))


def _limit_file_size(limit: int) -> None:
    import resource
    signal.signal(signal.SIGXFSZ, signal.SIG_IGN)
    resource.setrlimit(resource.RLIMIT_FSIZE, (limit, limit))


@pytest.mark.parametrize("target", ["/dev/full", "/dev/zero", "directory", "no-permission"])
def test_replay_exits_1_when_the_jsonl_cannot_be_opened(recording, tmp_path, target):
    """The README says 1; it was 0 (a directory, no permission) or a hang reading /dev/zero."""
    if target == "directory":
        path = str(tmp_path)
    elif target == "no-permission":
        if os.geteuid() == 0:
            pytest.skip("root may write anywhere")
        folder = tmp_path / "ro"
        folder.mkdir(mode=0o500)
        path = str(folder / "s.jsonl")
    else:
        path = target
    run = run_measured(edge_monitor("replay", str(recording), "--jsonl", path), timeout=300)
    assert run.returncode == 1 and "JSONL output" in run.stderr and "Traceback" not in run.stderr, run.stderr
    assert run.max_rss_mb < 1000


@pytest.fixture
def tiny_tmpfs(tmp_path):
    """A 64 KiB tmpfs (root only; skipped where it cannot be mounted), unmounted afterwards."""
    mount = tmp_path / "tmpfs"
    mount.mkdir()
    if os.geteuid() != 0:
        pytest.skip("mounting a tmpfs needs root")
    done = subprocess.run(["mount", "-t", "tmpfs", "-o", "size=64k", "tmpfs", str(mount)],
                          capture_output=True, text=True)
    if done.returncode != 0:
        pytest.skip(f"cannot mount a tmpfs here: {done.stderr.strip()}")
    try:
        yield mount
    finally:
        subprocess.run(["umount", "-l", str(mount)], capture_output=True)


def test_a_real_enospc_under_jsonl_and_state(recording, tiny_tmpfs):
    """The issue's reproducer on a real full filesystem: a traceback, exit 0, sink_errors 0 and a torn
    last line before; now whole lines, the failures counted, exit 1, and after freeing space the next
    replay adds the missing records (the earlier ones are recognised as repeats)."""
    filler = tiny_tmpfs / "filler"
    filler.write_bytes(bytes(56 << 10))           # 8 KiB left: a few records
    jsonl, state = tiny_tmpfs / "s.jsonl", tiny_tmpfs / "state"
    args = edge_monitor("replay", str(recording), "--json", "--jsonl", str(jsonl), "--state-dir", str(state))
    run = run_measured(args, timeout=600)
    assert run.returncode == 1 and "Traceback" not in run.stderr, run.stderr[-3000:]
    stats = json.loads(run.stdout)
    first = _whole_lines(jsonl)
    assert stats["details"]["sink_errors"] == stats["symptoms"] - len(first) > 0
    filler.unlink()
    again = run_measured(args, timeout=600)
    assert again.returncode == 0, again.stderr[-3000:]
    assert sorted((r["joint"], r["cycle"]) for r in _whole_lines(jsonl)) == sorted(
        {(j, c) for j in (0, 1) for c in range(3)})


def test_state_saves_fail_and_monitoring_goes_on(tmp_path, monkeypatch):
    """In process: a save that raises ENOSPC returns False, is counted in health state_save_errors
    and leaves the previous state file as it was."""
    import errno

    from edge_monitor.config import AgentConfig
    from edge_monitor.pipeline import state_store
    from edge_monitor.pipeline.agent import Agent

    store = state_store.StateStore(tmp_path)
    agent = Agent(AgentConfig(), state_store=store)
    assert agent.save_state()
    before = (tmp_path / STATE_FILE).read_bytes()

    def full(*_args, **_kwargs):
        raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))

    monkeypatch.setattr(state_store.os, "fsync", full)
    assert not agent.save_state() and not agent.save_state()
    assert agent.health().counters["state_save_errors"] == 2 and store.last_save_error
    assert (tmp_path / STATE_FILE).read_bytes() == before and not list(tmp_path.glob(".agent_state.*"))
    monkeypatch.undo()
    assert agent.save_state() and store.last_save_error is None
    agent.close()


if __name__ == "__main__":      # pragma: no cover
    sys.exit(pytest.main([__file__, "-q"]))
