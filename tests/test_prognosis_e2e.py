"""The prognosis end to end, as a user runs it (docs/PROGNOSIS.md): the simulator records a robot whose
joint 1 wears, `edge-monitor replay` of the log prints the forecast in its table, its JSON summary and
JSONL lines carry it and validate against the shipped schemas, the fault's alarm record says when, and
the healthy joint forecasts nothing."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import jsonschema
import pytest

from edge_monitor.schemas import load_schema

pytestmark = [pytest.mark.slow, pytest.mark.timeout(1200)]

BIN = Path(sys.executable).parent
#: The demo's robot: 2 joints, its 4 designed speeds, joint 1 wearing 0 → 60 over cycles 85 … 205.
SIM = ["--joints", "2", "--cycles", "170", "--seed", "7", "--speeds", "31.6,36.6,41.6,46.6",
       "--wear-law", "1:ramp:start=85,end=205,from=0,to=60", "--start-time", "1795000000"]


def validate(kind: str, record: dict) -> None:
    jsonschema.validate(record, load_schema(kind), format_checker=jsonschema.Draft202012Validator.FORMAT_CHECKER)


@pytest.fixture(scope="module")
def replayed(tmp_path_factory):
    out = tmp_path_factory.mktemp("prognosis")
    log, truth = out / "run.blf", out / "truth.jsonl"
    subprocess.run([BIN / "sim-controller", "record", "-o", log, "--truth", truth, *SIM], check=True,
                   capture_output=True, timeout=600)
    config = out / "agent.toml"
    config.write_text('[segmentation]\nspeeds = [31.6, 36.6, 41.6, 46.6]\n')
    table = subprocess.run([BIN / "edge-monitor", "replay", log, "--config", config, "--jsonl", out / "s.jsonl"],
                           check=True, capture_output=True, text=True, timeout=900).stdout
    summary = json.loads(subprocess.run([BIN / "edge-monitor", "replay", log, "--config", config, "--json"],
                                        check=True, capture_output=True, text=True, timeout=900).stdout)
    lines = [json.loads(x) for x in (out / "s.jsonl").read_text().splitlines()]
    wear = {(r["joint"], r["cycle"]): r["wear"] for r in map(json.loads, truth.read_text().splitlines()) if "joint" in r}
    return {"table": table, "summary": summary, "lines": lines, "wear": wear}


def test_the_worn_joint_is_forecast_from_its_alarm_on_and_the_healthy_one_is_not(replayed):
    lines = replayed["lines"]
    raised = [r for r in lines if r.get("kind") == "alarm" and r["state"] == "raised" and r["joint"] == 1]
    assert raised, "the worn joint raised no fault"
    first = raised[0]["prognosis"]
    assert first["state"] in ("forecast", "critical") and "critical wear 35" in first["text"]
    symptoms = [r for r in lines if "kind" not in r]
    healthy = [r["prognosis"] for r in symptoms if r["joint"] == 0 and not r["alarm"]]
    assert healthy and {p["state"] for p in healthy} <= {"learning", "no_trend"}
    # the worn joint's forecasts after its alarm: where the remaining life is known from the truth, the
    # state agrees with it at the end (the log ends at cycle 169: true wear 42, past critical)
    worn = [r for r in symptoms if r["joint"] == 1]
    assert worn[-1]["prognosis"]["state"] == "critical" and replayed["wear"][(1, 169)] >= 35
    for r in lines:
        validate(r.get("kind", "symptom"), {k: v for k, v in r.items() if k != "kind"})


def test_the_replay_summary_and_table_show_the_forecast(replayed):
    summary = replayed["summary"]
    validate("summary", summary)
    assert set(summary["prognosis"]) == {"0", "1"} and summary["prognosis"]["1"]["state"] == "critical"
    table = replayed["table"]
    assert "critical in" in table and "fault raised at cycle" in table and "critical wear 35" in table
