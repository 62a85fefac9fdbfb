"""Acknowledging an alarm: the decision layer (DetectorBank), the agent (sinks, persistence across a
restart) and the request payload (validated, size-capped; never a traceback)."""

from __future__ import annotations

import json

import numpy as np
import pytest

from edge_monitor.pipeline.detectors import DecisionConfig, DetectorBank

QUANTITIES = ("wear", "kl_raw", "kl_weighted")


def small_bank() -> DetectorBank:
    config = DecisionConfig(n_nominal=20, density="gauss", calibration_draws=16, calibration_steps=400,
                            quantities=QUANTITIES, steady_relearn=False)
    return DetectorBank(config, {})


def healthy(rng: np.random.Generator) -> dict[str, float]:
    return {"wear_score": float(rng.normal()), "kl_raw": float(np.exp(rng.normal(-3, 0.3))),
            "kl_weighted": float(np.exp(rng.normal(-4, 0.3)))}


def feed(bank: DetectorBank, rng: np.random.Generator, cycles: range, wear_shift: float = 0.0):
    """Feed ``cycles``; the decisions of the last cycle and every alarm raised."""
    raised, decisions = [], {}
    for cycle in cycles:
        values = healthy(rng)
        values["wear_score"] += wear_shift
        decisions, alarms = bank.update(values, "r1", 2, cycle)
        raised += alarms
    return decisions, raised


@pytest.fixture
def latched() -> tuple[DetectorBank, np.random.Generator]:
    """A bank whose wear detector has latched an alarm (an 8σ step of the wear score); KL quiet."""
    rng = np.random.default_rng(3)
    bank = small_bank()
    feed(bank, rng, range(60))
    decisions, raised = feed(bank, rng, range(60, 66), wear_shift=8.0)
    assert [(a.quantity, a.state) for a in raised] == [("wear", "raised")]
    assert decisions["wear"].alarm and not decisions["kl_raw"].alarm
    return bank, rng


def test_a_latched_alarm_is_acknowledged_and_the_statistic_restarts_on_the_same_threshold(latched):
    bank, rng = latched
    threshold = bank.detectors["wear"].threshold
    result = bank.acknowledge("r1", 2, 65)
    assert [a.to_dict() for a in result.alarms] == [
        {"schema": 1, "robot": "r1", "joint": 2, "cycle": 65, "quantity": "wear", "state": "acknowledged",
         "statistic": None, "threshold": threshold, "miss_probability": None, "change_cycle": None}]
    assert result.not_latched == ("kl_raw", "kl_weighted")       # asked for (all), nothing latched: no-op
    decisions, raised = feed(bank, rng, range(66, 67))
    wear = decisions["wear"]
    assert not wear.alarm and raised == []
    assert wear.state == "monitoring" and wear.threshold == threshold       # same nominal and threshold
    assert wear.statistic is not None and wear.statistic < threshold         # one healthy value since the restart
    assert wear.change_cycle == 66                                           # the window starts after the restart
    _, raised = feed(bank, rng, range(67, 75), wear_shift=8.0)               # the fault again: a new alarm
    assert [(a.quantity, a.state) for a in raised] == [("wear", "raised")]


def test_nothing_latched_is_a_no_op_reported_as_such():
    rng = np.random.default_rng(4)
    bank = small_bank()
    feed(bank, rng, range(40))
    before = json.dumps(bank.state_dict(), sort_keys=True)
    result = bank.acknowledge("r1", 2, 39, ["kl_raw", "wear", "kl_raw"])
    assert result.alarms == () and result.not_latched == ("kl_raw", "wear")
    assert json.dumps(bank.state_dict(), sort_keys=True) == before               # state untouched


def test_a_quantity_that_is_not_watched_is_refused_and_changes_nothing(latched):
    bank, _ = latched
    with pytest.raises(ValueError, match=r"'joint' is not watched; watched: wear, kl_raw, kl_weighted"):
        bank.acknowledge("r1", 2, 65, ["wear", "joint"])
    assert bank.detectors["wear"].alarmed


def test_only_the_named_quantities_are_acknowledged(latched):
    bank, _ = latched
    assert bank.acknowledge("r1", 2, 65, ["kl_raw"]).not_latched == ("kl_raw",)
    assert bank.detectors["wear"].alarmed
    assert [a.quantity for a in bank.acknowledge("r1", 2, 65, ["wear"]).alarms] == ["wear"]


def test_an_acknowledgement_survives_a_state_save_and_restore(latched):
    bank, rng = latched
    unacknowledged = DetectorBank(bank.config, {})
    unacknowledged.load_state(json.loads(json.dumps(bank.state_dict())), 2)
    bank.acknowledge("r1", 2, 65)
    restored = DetectorBank(bank.config, {})
    assert restored.load_state(json.loads(json.dumps(bank.state_dict())), 2) == []
    assert unacknowledged.detectors["wear"].alarmed          # the other side: a saved latch is restored
    assert not restored.detectors["wear"].alarmed
    values = healthy(rng)
    (after, raised), (control, _) = (b.update(values, "r1", 2, 66) for b in (restored, bank))
    assert raised == [] and after["wear"] == control["wear"]     # continues exactly as the live bank
