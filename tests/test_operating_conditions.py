"""A load change after learning is not wear (issue "robust to operating conditions"): the agent on the
simulator's fast path, two warm joints with the default individual variation, every detector in its
steady stage, the test cycle's load range moved after learning. Both sides: no alarm on healthy joints
(an advisory says the load left the learned range), and a wear ramp on one joint after the step still
alarms on wear and on a distribution quantity before the critical wear, on that joint only.

Small learning settings so that the steady stage is reached in ≈ 150 cycles: the joints start warm
(55 °C, near their running temperature), the settling test looks at 80 cycles for a slope ≤ 0.05 °C per
cycle (the shipped 240 and 0.02 would take ≈ 300 more cycles), the steady nominal is learned from 60; the thresholds are the agent's own (ARL0 10⁴ per detector)."""

from __future__ import annotations

from typing import Any

import pytest

from edge_monitor.config import config_from_mapping
from edge_monitor.offline.fast_path import run_cycles
from edge_monitor.pipeline.agent import Agent
from sim_controller.config import SimConfig, wear_profiles_from_ramps
from sim_controller.cycle_mode import cycle_signals
from sim_controller.timeline import PlantEvent

pytestmark = pytest.mark.timeout(1800)      # ≈ 2 × 290 cycles of 2 joints: minutes on a loaded machine

STEP, CYCLES = 170, 290
# a stated 10⁴ cycles per detector, not the default budget (2.6·10⁶): with a 60-cycle steady nominal the
# thresholds for the budget are far out in an extrapolated tail; what the budget costs on a load step is
# measured with the shipped settings in docs/DETECTION.md ("The false-alarm budget")
SETTINGS = {"decision": {"settling_window": 80, "settling_max_rate": 0.05, "steady_nominal": 60,
                         "arl0_cycles": 1e4}}


def _run(load_range: tuple[float, float], seed: int, ramp: str | None = None) -> list[dict[str, Any]]:
    sim = SimConfig(joints=2, cycles=CYCLES, seed=seed, start_temperature=55.0,
                    timeline=(PlantEvent(STEP, load_range=load_range),),
                    wear=wear_profiles_from_ramps([ramp], 2) if ramp else ())
    agent = Agent(config_from_mapping(SETTINGS))
    return [s.to_dict() | {"alarms": [a.to_dict() for a in s.alarms],
                           "advisories": [a.to_dict() for a in s.advisories]}
            for s in run_cycles(agent, cycle_signals(sim))]


def _steady_before_step(records: list[dict[str, Any]]) -> None:
    """The premise: every detector of both joints monitors on its steady nominal before the step."""
    for joint in (0, 1):
        last = [r for r in records if r["joint"] == joint and r["cycle"] == STEP - 1][0]
        for quantity, decision in last["decisions"].items():
            assert decision["state"] == "monitoring", (joint, quantity, decision)
            assert decision["calibration"]["stage"] == "steady", (joint, quantity)


@pytest.mark.slow
@pytest.mark.parametrize("load_range,seed", [((0.6, 1.0), 61), ((0.4, 0.8), 62)])
def test_a_load_step_on_healthy_warm_joints_raises_no_alarm_only_an_advisory(load_range, seed) -> None:
    records = _run(load_range, seed)
    _steady_before_step(records)
    alarms = [a for r in records for a in r["alarms"]]
    assert alarms == []
    entered = {(a["joint"], a["covariate"]) for r in records for a in r["advisories"] if a["state"] == "entered"}
    assert all(r["cycle"] >= STEP for r in records                          # no load advisory before the step
               if any(a["covariate"] == "load" for a in r["advisories"]))
    # the step's load, and the motor temperature (a heavier load heats the motor: 71–73 °C 70–100 cycles
    # after the step to 0.6–1.0, learned 53–68 °C; a range learned from 60 cycles is narrow) are operating
    # conditions, never alarms
    assert {covariate for _, covariate in entered} <= {"load", "motor_temperature"}
    if load_range[1] >= 0.9:       # well outside 0.3–0.7: both joints say so
        assert {(0, "load"), (1, "load")} <= entered
        after = [r for r in records if r["cycle"] >= STEP + 5]
        assert sum("load" in r["operating"]["outside"] for r in after) > len(after) / 2


@pytest.mark.slow
def test_wear_after_a_load_step_still_alarms_before_the_critical_wear_on_that_joint_only() -> None:
    records = _run((0.6, 1.0), 63, ramp=f"1:{STEP + 10}:{CYCLES}:0:50")
    _steady_before_step(records)
    faults = [a for r in records for a in r["alarms"] if a["state"] in ("raised", "updated")]
    assert {a["joint"] for a in faults} == {1}
    evidence = [e for a in faults for e in a["detectors"]]        # one fault, its detectors as they agree
    first: dict[str, int] = {}
    for e in evidence:
        first.setdefault(e["quantity"], e["cycle"])
    true_wear = {r["cycle"]: 50.0 * max(0, r["cycle"] - STEP - 10) / (CYCLES - STEP - 10)
                 for r in records if r["joint"] == 1}
    assert "wear" in first and true_wear[first["wear"]] < 35.0
    distribution = [q for q in ("kl_raw", "kl_weighted", "joint") if q in first]
    assert distribution and min(true_wear[first[q]] for q in distribution) < 35.0
    cause = next(e["cause"] for e in evidence if e["quantity"] == "wear")
    assert cause["operating"]["learned"]["load"][1] < 0.75 and cause["delta"][0] > 0
