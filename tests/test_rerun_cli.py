"""The Rerun installation around the SDK, with the real `rerun` CLI: usage reporting turned off in the
config Rerun reads (Rerun itself then reports it disabled, and keeps it so), and a recording compacted in
place when it is closed, still accepted by `rerun rrd verify`."""

from __future__ import annotations

import json
import os
import re
import subprocess

import pytest

from edge_monitor.sinks import rerun_cli
from edge_monitor.sinks.rerun_view import IMMEDIATE, RerunSink


@pytest.fixture
def home(tmp_path, monkeypatch):
    monkeypatch.setenv("HOME", str(tmp_path))
    monkeypatch.delenv("XDG_CONFIG_HOME", raising=False)
    monkeypatch.delenv("XDG_DATA_HOME", raising=False)
    monkeypatch.setattr(rerun_cli, "_checked", set())
    return tmp_path


def _rerun(*args: str) -> subprocess.CompletedProcess[str]:
    executable = rerun_cli.rerun_executable()
    assert executable, "the rerun CLI of rerun-sdk is not installed"
    return subprocess.run([executable, *args], capture_output=True, text=True, timeout=120, env=dict(os.environ))


def test_usage_reporting_is_off_as_rerun_itself_reads_it(home):
    assert rerun_cli.usage_reporting_off()
    done = _rerun("analytics", "config")
    assert done.returncode == 0 and "failed to load" not in done.stderr, done.stderr
    config = json.loads(done.stdout[done.stdout.index("{"):])
    assert config["analytics_enabled"] is False
    assert config["config_file_path"] == str(home / ".config" / "rerun" / "analytics.json")
    _rerun("rrd", "--help")                      # a later use of the CLI keeps it off
    assert json.loads(rerun_cli.analytics_config_path().read_text())["analytics_enabled"] is False


def test_a_user_who_enabled_it_gets_it_turned_off_again_keeping_the_id(home):
    _rerun("analytics", "enable")
    before = json.loads(rerun_cli.analytics_config_path().read_text())
    assert before["analytics_enabled"] is True
    assert rerun_cli.usage_reporting_off()
    after = json.loads(rerun_cli.analytics_config_path().read_text())
    assert after["analytics_enabled"] is False and after["analytics_id"] == before["analytics_id"]


def test_a_saved_recording_is_compacted_when_closed_and_stays_valid(home, tmp_path):
    path = tmp_path / "r.rrd"
    sink = RerunSink.open(f"save:{path}", batching=IMMEDIATE)   # drawn record by record: many small chunks
    for cycle in range(30):
        sink.log_symptom({"robot": "r1", "joint": 0, "cycle": cycle, "t": 10.0 * cycle,
                          "wear": {"estimate": 0.5 * cycle, "std": 1.0, "temperature": 40.0},
                          "kl": {"raw": 0.01, "weighted": 0.02}, "friction": {"speeds": [20.0], "torque": [0.05]},
                          "decisions": {}, "critical_wear": 35.0})
    sink.close()
    assert not (tmp_path / "r.rrd.compacting").exists()
    assert _rerun("rrd", "verify", str(path)).returncode == 0
    stats = _rerun("rrd", "stats", str(path))
    assert re.search(r"effective:\s+\d+ chunks \(1\.0×\)", stats.stdout), stats.stdout[-1500:]
