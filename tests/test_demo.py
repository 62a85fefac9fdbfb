"""The README's main job, `edge-monitor demo`, in a reduced form: simulator process → pty slcan →
agent → Zenoh → independent subscriber, Rerun recording read back."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest

from recordings import rows_by_entity

pytestmark = pytest.mark.slow


def test_demo_reduced(tmp_path: Path):
    out, summary_path, rrd = tmp_path / "demo", tmp_path / "summary.json", tmp_path / "demo.rrd"
    cycles, joints = 6, 2
    proc = subprocess.run(
        [sys.executable, "-m", "edge_monitor.cli", "demo", "--cycles", str(cycles), "--joints", str(joints),
         "--nominal-cycles", "10", "--out", str(out), "--rerun", f"save:{rrd}", "--json-summary", str(summary_path)],
        capture_output=True, text=True, timeout=600)
    assert proc.returncode == 0, proc.stdout + proc.stderr
    summary = json.loads(summary_path.read_text())
    # every frame the simulator put on the link arrived and passed the E2E checks
    assert summary["frames"]["frames_total"] == summary["frames_sent"] == summary["frames"]["frames_ok"]
    # every cycle of every joint produced a symptom, and the independent subscriber got them all
    assert summary["cycles"] == cycles
    assert summary["symptoms_published"] == summary["symptoms_received"] == cycles * joints
    assert summary["rrd"] == str(rrd)
    lines = [json.loads(x) for x in (out / "symptoms.jsonl").read_text().splitlines()]
    symptoms = [r for r in lines if "kind" not in r]          # alarm events are marked "kind": "alarm"
    alarms = [r for r in lines if r.get("kind") == "alarm"]
    assert [(a["joint"], a["cycle"], a["quantity"]) for a in alarms if a["state"] == "raised"] == \
        [(a["joint"], a["cycle"], a["quantity"]) for a in summary["alarms"]]
    assert sorted((s["joint"], s["cycle"]) for s in symptoms) == [(j, c) for j in range(joints) for c in range(cycles)]
    assert all(len(s["friction"]["speeds"]) == 4 for s in symptoms)
    assert "joint" in proc.stdout and "symptoms published" in proc.stdout    # the summary table

    rows = rows_by_entity(rrd)
    for j in range(joints):
        assert rows[f"/robot/demo-robot/joint/{j}/wear/estimate"] == cycles
        assert rows[f"/robot/demo-robot/joint/{j}/friction/curve"] == cycles
