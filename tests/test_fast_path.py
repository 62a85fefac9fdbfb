"""The simulator's cycle-level mode fed to the agent gives the same per-cycle quantities, statistics and
thresholds as the full frame path (`sim-controller record` → `edge-monitor replay`) with the same seed."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from edge_monitor.config import config_from_mapping
from edge_monitor.offline.fast_path import run_cycles
from edge_monitor.pipeline.agent import Agent
from sim_controller.config import SimConfig, wear_profiles_from_ramps
from sim_controller.cycle_mode import cycle_signals

AGENT_TOML = """
[model]
enabled = false
[kl]
n_nominal_cycles = 2
[decision]
n_nominal = 5
density = "gauss"
density_joint = "gauss"
"""


@pytest.mark.slow
def test_cycle_mode_gives_the_frame_path_quantities(tmp_path: Path):
    sim_args = ["--joints", "2", "--cycles", "9", "--seed", "5", "--wear-ramp", "1:0:9:0:40"]
    log, config = tmp_path / "run.blf", tmp_path / "agent.toml"
    config.write_text(AGENT_TOML)
    subprocess.run([sys.executable, "-m", "sim_controller.cli", "record", "--out", str(log), *sim_args],
                   check=True, capture_output=True, timeout=300)
    jsonl = tmp_path / "frames.jsonl"
    subprocess.run([sys.executable, "-m", "edge_monitor.cli", "replay", str(log), "--config", str(config),
                    "--jsonl", str(jsonl)], check=True, capture_output=True, timeout=300)
    framed = [r for r in map(json.loads, jsonl.read_text().splitlines()) if "kind" not in r]

    agent_config = config_from_mapping({"model": {"enabled": False}, "kl": {"n_nominal_cycles": 2},
                                        "decision": {"n_nominal": 5, "density": "gauss", "density_joint": "gauss"}})
    sim = SimConfig(joints=2, cycles=9, seed=5, wear=wear_profiles_from_ramps(["1:0:9:0:40"], 2))
    fast = [s.to_dict() for s in run_cycles(Agent(agent_config), cycle_signals(sim))]

    assert [(s["joint"], s["cycle"]) for s in fast] == [(s["joint"], s["cycle"]) for s in framed]
    assert len(fast) == 18
    thresholds: list[str] = []
    for a, b in zip(fast, framed):
        np.testing.assert_allclose(a["friction"]["torque"], b["friction"]["torque"], rtol=1e-12, atol=1e-15)
        for section, key in (("wear", "estimate"), ("wear", "temperature"), ("kl", "raw"), ("kl", "weighted")):
            if b[section][key] is None:
                assert a[section][key] is None
            else:   # sums over differently split sample blocks differ in the last bits; optimisers amplify that
                assert a[section][key] == pytest.approx(b[section][key], rel=1e-6, abs=1e-9), (section, key)
        assert a["load"] == pytest.approx(b["load"])
        for quantity, decision in b["decisions"].items():
            assert a["decisions"][quantity]["state"] == decision["state"]
            if decision["statistic"] is not None:
                assert a["decisions"][quantity]["statistic"] == pytest.approx(decision["statistic"], rel=1e-6)
            # the same thresholds: a scalar's depends only on the settings, the joint vector's on the
            # correlation of its learned values (equal here to ~1e-6), through a simulation with fixed draws
            if decision["threshold"] is not None:
                thresholds.append(quantity)
                assert a["decisions"][quantity]["threshold"] == pytest.approx(decision["threshold"], rel=1e-3)
    assert {"wear", "kl_raw", "kl_weighted", "joint"} <= set(thresholds)


def test_detector_inputs_are_the_symptoms_values_once_each_joint_has_learned() -> None:
    """The studies' input: every (joint, cycle) whose symptom carries the wear score and both KL
    distances, with exactly those values, and none of the learning cycles before."""
    from edge_monitor.offline.fast_path import DETECTOR_INPUTS, detector_inputs

    sim = SimConfig(joints=2, cycles=45, seed=5)
    rows = list(detector_inputs(sim))
    symptoms = [s.to_dict() for s in run_cycles(Agent(config_from_mapping({"decision": {"enabled": False}})),
                                                 cycle_signals(sim))]
    complete = [(s["joint"], s["cycle"], {"wear_score": s["wear"]["score"], "kl_raw": s["kl"]["raw"],
                                          "kl_weighted": s["kl"]["weighted"]})
                for s in symptoms if "score" in (s.get("wear") or {}) and (s.get("kl") or {}).get("raw") is not None
                and s["kl"].get("weighted") is not None]
    assert rows == complete and 0 < len(rows) < len(symptoms)
    assert all(tuple(values) == DETECTOR_INPUTS for _, _, values in rows)


def test_detector_inputs_carry_each_joint_cycles_truth_and_honour_agent_settings() -> None:
    """The truth paired with a row is the simulator's record of that joint and cycle; agent settings
    reach the agent (a KL sample selection changes the KL values, not the wear score)."""
    from edge_monitor.offline.fast_path import detector_inputs_with_truth

    sim = SimConfig(joints=2, cycles=40, seed=5)
    rows = list(detector_inputs_with_truth(sim))
    assert rows and all(truth["joint"] == joint and truth["cycle"] == cycle for joint, cycle, _, truth in rows)
    assert all(25.0 < truth["temperature"] < 60.0 for *_, truth in rows)
    other = list(detector_inputs_with_truth(sim, {"kl": {"min_speed": 1.0}}))
    assert [r[:2] for r in other] == [r[:2] for r in rows]
    assert [r[2]["wear_score"] for r in other] == [r[2]["wear_score"] for r in rows]
    assert all(a[2]["kl_raw"] != b[2]["kl_raw"] for a, b in zip(other, rows))
