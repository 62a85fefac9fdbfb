"""The product's promise on the simulator's defaults (individual variation, thermal drift, load spread),
both sides in one robot: a healthy joint raises no alarm, a joint whose gearbox wears does.

Why "no alarm" is a fair check and not a tuned one: every detector's threshold is calibrated for a
mean run length to false alarm of 10⁴ cycles at the drift allowance boundary (docs/DETECTION.md). The
healthy joint is monitored for ≈ 4 × 110 detector-cycles (4 quantities, monitoring from cycle ≈ 90), so
the expected number of false alarms is ≈ 0.04 if its drift stays inside the allowance; an alarm here
means the drift left the nominal behaviour the issue asks for. The worn joint's wear rises 0 → 60
(critical 35) from cycle 100 on: by cycle 200 its friction has moved by several nominal standard
deviations, which every quantity is designed to see (the alarm side).
"""

from __future__ import annotations

import pytest

from studies.robots import RunSpec, run_robot
from studies.tally import summarise

pytestmark = [pytest.mark.slow, pytest.mark.timeout(1800)]


def test_healthy_joint_stays_quiet_and_a_wearing_joint_alarms_under_default_drift() -> None:
    run = run_robot(RunSpec(seed=3, cycles=200, joints=2, wear_ramps=("1:100:200:0:60",), progress=0))
    assert run["temperature"][1] - run["temperature"][0] > 5.0, "the lubricant must actually drift"
    healthy = [a for a in run["alarms"] if a["joint"] == 0]
    worn = [a for a in run["alarms"] if a["joint"] == 1]
    assert set(run["monitored"]["0"]) == {"wear", "kl_raw", "kl_weighted", "joint"}
    # the wear detector decides every cycle after learning; the KL and joint-vector detectors hold while
    # the joint is warmer than they learned at (docs/DETECTION.md, "Operating conditions"), so they decide
    # on fewer cycles, but on at least half of the wear detector's: the quiet side is still watched
    monitored = run["monitored"]["0"]
    assert monitored["wear"] >= 100 and min(monitored.values()) >= monitored["wear"] / 2, run["monitored"]
    assert healthy == [], healthy
    assert worn, "a 0 → 60 wear ramp went unnoticed"
    assert min(a["cycle"] for a in worn) > 100                     # nothing before the wear starts
    summary = summarise([run])
    assert summary["false_alarms"] == 0
    assert summary["detections"][0]["first_alarm"]["joint"] == 1


def test_after_warm_up_the_steady_detectors_stay_quiet_and_still_find_wear() -> None:
    """The same promise once the joints are warm (docs/DETECTION.md, "Two stages"): 1 150 cycles, the
    lubricant settling near 58 °C; each joint's detectors learn their steady nominal once its motor
    temperature has settled (cycle ≈ 500–700 + 240 learning cycles) and from then on run at the stated
    ARL0 = 10⁴ cycles. The healthy joint is watched for ≈ 4 × 250 steady detector-cycles (expected
    false alarms ≈ 0.1) plus its warm-up; joint 1's wear ramps 0 → 60 from cycle 1 000, after its
    steady stage began, and must be found then, not before."""
    run = run_robot(RunSpec(seed=3, cycles=1150, joints=2, wear_ramps=("1:1000:1150:0:60",),
                                        progress=0))
    for joint in ("0", "1"):
        steady = run["steady_from"][joint]
        assert set(steady) == {"wear", "kl_raw", "kl_weighted", "joint"}, run["steady_from"]
        assert max(steady.values()) < 950, run["steady_from"]
    assert [a for a in run["alarms"] if a["joint"] == 0] == []
    worn = [a for a in run["alarms"] if a["joint"] == 1]
    assert worn and min(a["cycle"] for a in worn) > 1000, worn
