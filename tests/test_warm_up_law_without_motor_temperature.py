"""A joint whose controller sends no motor temperature has its own warm-up law (``[decision.warm_up_law_friction]``,
the wear score's measured on such robots): its detectors follow the lubricant temperature the wear estimate reads
from the friction, and its wear score spreads wider with a heavier upper tail (edge_monitor/pipeline/healthy_drift.py,
docs/WITHOUT_MOTOR_TEMPERATURE.md). The detector bank calibrates for the temperature its joint has, keeps that across
a restart, and re-derives on the same nominals when a motor temperature appears."""

from __future__ import annotations

import json
import math
from dataclasses import replace

import numpy as np
import pytest

from edge_monitor.config import ConfigError, config_from_mapping
from edge_monitor.pipeline.detectors import DetectorBank
from edge_monitor.pipeline.healthy_drift import WARM_UP_LAW, WARM_UP_LAW_FRICTION
from edge_monitor.pipeline.nominal_temperature import FRICTION_TEMPERATURE, MOTOR_TEMPERATURE


def test_the_law_without_motor_temperature_reaches_the_wear_detector_alone_and_is_validated() -> None:
    """The shipped law, stated for the wear score, reaches its warm-up calibration (skew included) on a joint without
    motor temperature only, and there the joint vector's wear axis (its KL axes from the KL distances' laws); the KL
    detectors stay as on a joint with one.
    ``[]`` gives the input back to ``warm_up_law`` (and the joint vector to its learning error); another input may be
    listed; a bad law names its key."""
    law = WARM_UP_LAW_FRICTION["wear_score"]
    decision = config_from_mapping({}).decision
    motor, friction = decision.detector_config("wear"), decision.detector_config("wear", friction_temperature=True)
    assert motor.spread_mean == (WARM_UP_LAW["wear_score"][2],) and motor.warm_up_skew == ()
    assert (friction.drift_mean, friction.drift_sd, friction.spread_mean, friction.spread_sd, friction.warm_up_skew) \
        == ((law[0],), (law[1],), (law[2],), (law[3],), (law[5],))
    assert friction.calibration("steady") == motor.calibration("steady")
    for quantity in ("kl_raw", "kl_weighted"):
        assert decision.detector_config(quantity, friction_temperature=True) == decision.detector_config(quantity)
    joint = decision.detector_config("joint", friction_temperature=True)    # every axis from its law, none wander
    assert joint.spread_mean == (law[2], WARM_UP_LAW["kl_raw"][2], WARM_UP_LAW["kl_weighted"][2])
    assert joint.drift_mean == (law[0], WARM_UP_LAW["kl_raw"][0], WARM_UP_LAW["kl_weighted"][0])
    assert joint.warm_up_skew == (law[5], 0.0, 0.0) and joint.warm_up_wander == ()
    assert joint.calibration("steady") == decision.detector_config("joint").calibration("steady")
    given_back = config_from_mapping({"decision": {"warm_up_law_friction": {"wear_score": []}}}).decision
    for quantity in ("wear", "joint"):      # the law given back; the learned sd's prior is its own setting
        assert replace(given_back.detector_config(quantity, friction_temperature=True), sd_prior_count=(),
                       sd_prior_sd=()) == given_back.detector_config(quantity)
    listed = config_from_mapping({"decision": {"warm_up_law_friction": {"kl_raw": [-0.1, 0.1, 1.1, 0.1]}}}).decision
    assert listed.detector_config("kl_raw", friction_temperature=True).spread_mean == (1.1,)
    assert listed.detector_config("wear", friction_temperature=True) == friction      # the shipped wear law kept
    for bad in ({"wear_score": [0.0, 0.1, 0.0, 0.1]}, {"wear_score": [0.0, 0.1, 1.0, 0.1, 0.0, 11.0]}):
        with pytest.raises(ConfigError, match="decision.warm_up_law_friction.wear_score"):
            config_from_mapping({"decision": {"warm_up_law_friction": bad}})


#: The shipped law as a user states it (``[decision.warm_up_law_friction]``).
OPTION = {"decision": {"warm_up_law_friction": {"wear_score": list(WARM_UP_LAW_FRICTION["wear_score"])}}}


def _learned_bank(source: str) -> DetectorBank:
    """A joint's detectors with the shipped law stated, after their warm-up nominals, fed healthy values while the
    joint warms (0.2 °C a cycle: not settled, so they stay in the warm-up stage) from ``source``."""
    decision = config_from_mapping(OPTION).decision
    bank, rng = DetectorBank(decision, {}), np.random.default_rng(11)
    for cycle in range(decision.n_nominal + 2):
        bank.observe_temperature(30.0 + 0.2 * cycle, source)
        bank.update({"wear_score": float(rng.normal()), "kl_raw": math.exp(rng.normal(-4.0, 0.1)),
                     "kl_weighted": math.exp(rng.normal(-3.5, 0.1))}, "robot", 0, cycle)
    return bank


def test_the_bank_calibrates_for_its_joints_temperature_keeps_it_and_re_derives_when_a_motor_temperature_appears(
        ) -> None:
    """With the shipped law stated, on a joint without motor temperature the wear detector's warm-up threshold is that
    law's (read from the shipped table; another than on a joint with one); the KL detectors' are the same on both. A
    restart restores it as saved; the first motor temperature re-derives the wear threshold on the same nominal for
    the law of joints with one (the saved threshold decides until the re-derived one is in)."""
    with_motor, without = _learned_bank(MOTOR_TEMPERATURE), _learned_bank(FRICTION_TEMPERATURE)
    for bank in (with_motor, without):
        assert all(d.state == "monitoring" and d.stage == "warm-up" for d in bank.detectors.values())
    wear, wear_motor = without.detectors["wear"], with_motor.detectors["wear"]
    assert wear.calibration is not None and wear.calibration.method == "table"
    assert wear.calibrated_job is not None and wear.calibrated_job.skew == (OPTION["decision"]["warm_up_law_friction"]
                                                                           ["wear_score"][5],)
    assert wear.threshold is not None and wear_motor.threshold is not None and wear.threshold != wear_motor.threshold
    assert without.detectors["kl_raw"].threshold == with_motor.detectors["kl_raw"].threshold

    restored = DetectorBank(config_from_mapping(OPTION).decision, {})
    assert restored.load_state(json.loads(json.dumps(without.state_dict())), 0) == []
    assert restored.calibrated_for == FRICTION_TEMPERATURE
    assert restored.detectors["wear"].threshold == wear.threshold

    restored.observe_temperature(45.0, MOTOR_TEMPERATURE)        # re-derived, in use from the next value on
    restored.update({"wear_score": 0.0, "kl_raw": math.exp(-4.0), "kl_weighted": math.exp(-3.5)}, "robot", 0, 70)
    moved = restored.detectors["wear"]
    assert moved.config == wear_motor.config and moved.threshold == wear_motor.threshold
    assert moved.state_dict()["nominal"] == wear.state_dict()["nominal"]
