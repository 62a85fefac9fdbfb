"""The README's main job, `edge-monitor demo`, in a reduced form: simulator process → pty slcan →
agent → Zenoh → independent subscriber, Rerun recording read back."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import jsonschema
import pytest

from edge_monitor.schemas import load_schema

from recordings import rows_by_entity

pytestmark = pytest.mark.slow


def test_demo_reduced(tmp_path: Path):
    out, rrd = tmp_path / "demo", tmp_path / "demo.rrd"
    cycles, joints = 6, 2
    proc = subprocess.run(
        [sys.executable, "-m", "edge_monitor.cli", "demo", "--cycles", str(cycles), "--joints", str(joints),
         "--nominal-cycles", "10", "--out", str(out), "--rerun", f"save:{rrd}"],
        capture_output=True, text=True, timeout=600)
    assert proc.returncode == 0, proc.stdout + proc.stderr
    summary = json.loads((out / "summary.json").read_text())      # the same schema as run/replay --json
    jsonschema.validate(summary, load_schema("summary"))
    demo = summary["demo"]
    # every frame the simulator put on the link arrived and passed the E2E checks
    assert summary["frames_total"] == demo["frames_sent"] == summary["frames_ok"]
    # every cycle of every joint produced a symptom, and the independent subscriber got them all
    assert summary["cycles"] == cycles
    assert demo["symptoms_published"] == demo["symptoms_received"] == cycles * joints
    assert demo["rrd"] == str(rrd)
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
