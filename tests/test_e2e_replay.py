"""End-to-end replays of simulator logs through the agent, as a user runs them:
`sim-controller record` → `edge-monitor replay --json --jsonl`, with fixed seeds.

* every injected link fault is accounted for by the agent's E2E counters;
* the extracted friction matches the simulator's ground truth within its standard error;
* a golden replay: the symptom stream of a fixed-seed run equals the stored one
  (regenerate with UPDATE_GOLDEN=1 after an intended change, and say why in the commit).
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

GOLDEN = Path(__file__).parent / "golden" / "replay_seed11.json"


def run(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", *args], capture_output=True, text=True, timeout=600, check=True)


def record(tmp: Path, name: str, *extra: str) -> tuple[Path, list[dict], dict]:
    log, truth = tmp / f"{name}.blf", tmp / f"{name}.truth.jsonl"
    run("sim_controller.cli", "record", "--out", str(log), "--truth", str(truth), *extra)
    lines = [json.loads(x) for x in truth.read_text().splitlines()]
    return log, [r for r in lines if "joint" in r], lines[-1]


def replay(log: Path, jsonl: Path, *extra: str) -> tuple[dict, list[dict]]:
    out = run("edge_monitor.cli", "replay", str(log), "--json", "--jsonl", str(jsonl), *extra)
    return json.loads(out.stdout), [r for r in map(json.loads, jsonl.read_text().splitlines()) if "kind" not in r]


def test_link_faults_are_all_accounted_for(tmp_path: Path):
    log, truth, summary = record(tmp_path, "faults", "--joints", "2", "--cycles", "2", "--seed", "4",
                                 "--faults", "drop=0.002,corrupt=0.002,duplicate=0.001,reorder=0.001")
    faults = summary["faults"]
    assert min(faults["dropped"], faults["corrupted"], faults["duplicated"], faults["reordered"]) > 20
    stats, symptoms = replay(log, tmp_path / "faults.jsonl")
    wrong_sequence = stats["details"]["wrong_sequence"]
    assert stats["frames_total"] == summary["frames_sent"]          # frames put on the link (after drops)
    assert stats["crc_errors"] == faults["corrupted"]          # every 1–3 bit corruption is caught
    assert stats["repeated"] == faults["duplicated"]
    # a frame lost to a drop or to a failed CRC shows up as a counter gap; a reordered frame of the
    # same identifier is first counted as lost, then rejected as stale (wrong sequence)
    assert stats["counter_lost"] == faults["dropped"] + faults["corrupted"] + wrong_sequence
    assert stats["frames_ok"] == (stats["frames_total"] - faults["corrupted"] - faults["duplicated"]
                                  - wrong_sequence)
    assert len(symptoms) == 4 and all(len(s["friction"]["speeds"]) == 12 for s in symptoms)


def test_extracted_friction_matches_ground_truth(tmp_path: Path):
    log, truth, _ = record(tmp_path, "truth", "--joints", "2", "--cycles", "3", "--seed", "8",
                           "--temperature-range", "35:45", "--wear-ramp", "1:0:2:0:40")
    _, symptoms = replay(log, tmp_path / "truth.jsonl")
    by_key = {(t["joint"], t["cycle"]): t for t in truth}
    assert sorted(by_key) == sorted((s["joint"], s["cycle"]) for s in symptoms)
    z_all = []
    for s in symptoms:
        t = by_key[(s["joint"], s["cycle"])]
        f = s["friction"]
        assert f["speeds"] == pytest.approx(t["speeds"], abs=0.005)     # measured plateau speeds
        # the simulated joint really had the model friction plus the per-level model error
        applied = np.array(t["friction"]) + np.array(t["model_error"])
        z_all += list((np.array(f["torque"]) - applied) / np.array(f["stderr"]))
    z = np.array(z_all)
    # The standard errors are honest if the z-scores look standard normal: with 72 data, |mean| < 4/√72
    # and a standard deviation within a factor 2 (the AR(1) inflation is an approximation).
    assert abs(z.mean()) < 4 / np.sqrt(z.size), z
    assert 0.5 < z.std() < 2.0, z.std()


def _digest(symptoms: list[dict]) -> list[dict]:
    return [{"joint": s["joint"], "cycle": s["cycle"], "friction": s["friction"]["torque"],
             "wear": s["wear"]["estimate"], "temperature": s["wear"]["temperature"],
             "kl_raw": s["kl"]["raw"], "kl_weighted": s["kl"]["weighted"]} for s in symptoms]


@pytest.mark.slow
def test_golden_replay(tmp_path: Path):
    log, _, _ = record(tmp_path, "golden", "--joints", "2", "--cycles", "4", "--seed", "11")
    stats, symptoms = replay(log, tmp_path / "golden.jsonl")
    digest = {"frames_total": stats["frames_total"], "symptoms": _digest(symptoms)}
    if os.environ.get("UPDATE_GOLDEN"):
        GOLDEN.parent.mkdir(exist_ok=True)
        GOLDEN.write_text(json.dumps(digest, indent=1))
    golden = json.loads(GOLDEN.read_text())
    assert digest["frames_total"] == golden["frames_total"]
    assert len(digest["symptoms"]) == len(golden["symptoms"])
    for got, want in zip(digest["symptoms"], golden["symptoms"]):
        assert (got["joint"], got["cycle"]) == (want["joint"], want["cycle"])
        np.testing.assert_allclose(got["friction"], want["friction"], rtol=0, atol=1e-9)
        for key in ("wear", "temperature", "kl_raw", "kl_weighted"):
            if want[key] is None:
                assert got[key] is None, key
            else:   # optimiser results: allow for last-digit differences across BLAS builds
                assert got[key] == pytest.approx(want[key], rel=1e-4, abs=1e-6), key


def test_replay_of_a_missing_or_broken_file_says_what_is_wrong(tmp_path: Path):
    for path, words in ((tmp_path / "missing.blf", "not found"), (tmp_path / "broken.blf", "cannot read")):
        if path.name == "broken.blf":
            path.write_bytes(b"this is not a BLF file")
        proc = subprocess.run([sys.executable, "-m", "edge_monitor.cli", "replay", str(path)],
                              capture_output=True, text=True, timeout=120)
        assert proc.returncode == 1 and words in proc.stderr and "Traceback" not in proc.stderr   # runtime failure
