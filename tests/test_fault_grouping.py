"""One alarm per fault (edge_monitor/pipeline/fault_grouping.py): the crossings of one joint's detectors
grouped into faults — raised once, updated as more detectors agree, chattering soon after an
acknowledgement, a new fault after the chatter window, closed by an acknowledgement or a maintenance,
kept across a restart. Unit tests on hand-made crossings, both sides of every boundary; the real pipeline
is tests/test_fault_alarms.py."""

from __future__ import annotations

import json

import jsonschema
import pytest

from edge_monitor.config import ConfigError, config_from_mapping
from edge_monitor.pipeline.fault_grouping import AlarmConfig, FaultTracker, new_crossings
from edge_monitor.records import Alarm
from edge_monitor.schemas import load_schema

ROBOT, JOINT = "r1", 2


def crossing(quantity: str, cycle: int, statistic: float = 9.0) -> Alarm:
    """A detector's own crossing as DetectorBank.update reports it (with a cause, as the joint adds it)."""
    return Alarm(ROBOT, JOINT, cycle, quantity, "raised", statistic, 5.0, 0.1, cycle - 3,
                 cause={"delta": [1.5], "change_cycle": cycle - 3,
                        "operating": {"covariates": {"load": 0.5}, "learned": {"load": [0.4, 0.6]}, "outside": []}})


def acknowledgement(quantity: str, cycle: int) -> Alarm:
    return Alarm(ROBOT, JOINT, cycle, quantity, "acknowledged", threshold=5.0)


def tracker(chatter_cycles: int = 20) -> FaultTracker:
    return FaultTracker(AlarmConfig(chatter_cycles), ROBOT, JOINT)


def valid(record: Alarm) -> dict:
    out = json.loads(json.dumps(record.to_dict()))
    jsonschema.validate(out, load_schema("alarm"))
    return out


def test_a_fault_seen_by_several_detectors_is_one_raised_record_then_updates():
    faults = tracker()
    assert faults.crossings([], 10) == []
    [raised] = faults.crossings([crossing("wear", 10)], 10)
    [updated] = faults.crossings([crossing("kl_raw", 12), crossing("joint", 12)], 12)
    [again] = faults.crossings([crossing("kl_weighted", 15)], 15)
    records = [valid(r) for r in (raised, updated, again)]
    assert [r["state"] for r in records] == ["raised", "updated", "updated"]
    assert {r["fault"] for r in records} == {"r1/2/10"} and faults.raised == 1
    assert all(r["quantity"] == "wear" and r["statistic"] == 9.0 and r["open"] for r in records)
    assert [d["quantity"] for d in records[-1]["detectors"]] == ["wear", "kl_raw", "joint", "kl_weighted"]
    assert [d["cycle"] for d in records[-1]["detectors"]] == [10, 12, 12, 15]
    assert records[-1]["detectors"][1]["cause"]["delta"] == [1.5]          # each detector's evidence as today
    # the run statistics keep one entry per detector crossing, each with its fault
    assert [c["quantity"] for r in (raised, updated, again) for c in new_crossings(r)] == \
        ["wear", "kl_raw", "joint", "kl_weighted"]


def test_detectors_crossing_in_the_same_cycle_raise_one_fault_naming_both():
    [record] = tracker().crossings([crossing("kl_raw", 7), crossing("wear", 7)], 7)
    assert record.state == "raised" and record.quantity == "kl_raw"
    assert [d["quantity"] for d in record.detectors or ()] == ["kl_raw", "wear"]


@pytest.mark.parametrize("chatter_cycles", [20, 5])
def test_a_crossing_within_the_chatter_window_after_an_acknowledgement_is_the_same_fault_chattering(chatter_cycles):
    faults = tracker(chatter_cycles)
    faults.crossings([crossing("wear", 30)], 30)
    [ack] = faults.acknowledged([acknowledgement("wear", 31)], 31, latched=[])
    assert valid(ack)["state"] == "acknowledged" and ack.open is False and ack.fault == "r1/2/30"
    assert faults.open_fault is None
    # exactly at the window's end: still the same fault
    [chatter] = faults.crossings([crossing("wear", 31 + chatter_cycles)], 31 + chatter_cycles)
    assert (chatter.state, chatter.fault, chatter.open) == ("chattering", "r1/2/30", True)
    assert (chatter.detectors or ())[0]["crossings"] == 2 and faults.chattering == 1 and faults.raised == 1


@pytest.mark.parametrize("chatter_cycles", [20, 5])
def test_after_the_chatter_window_a_crossing_is_a_new_fault(chatter_cycles):
    faults = tracker(chatter_cycles)
    faults.crossings([crossing("wear", 30)], 30)
    faults.acknowledged([acknowledgement("wear", 31)], 31, latched=[])
    [new] = faults.crossings([crossing("wear", 32 + chatter_cycles)], 32 + chatter_cycles)
    assert (new.state, new.fault) == ("raised", f"r1/2/{32 + chatter_cycles}")
    assert faults.raised == 2 and faults.chattering == 0


def test_a_zero_window_never_chatters():
    faults = tracker(0)
    faults.crossings([crossing("wear", 30)], 30)
    faults.acknowledged([acknowledgement("wear", 30)], 30, latched=[])
    assert faults.crossings([crossing("wear", 31)], 31)[0].state == "raised"


def test_a_partial_acknowledgement_keeps_the_fault_open():
    faults = tracker()
    faults.crossings([crossing("wear", 40)], 40)
    faults.crossings([crossing("kl_raw", 41)], 41)
    [ack] = faults.acknowledged([acknowledgement("wear", 42)], 42, latched=["kl_raw"])
    assert ack.open is True and [d["quantity"] for d in ack.detectors or ()] == ["wear"]
    assert faults.open_fault == "r1/2/40"
    # the acknowledged detector again within the window: chattering; a detector that never crossed: agrees
    assert faults.crossings([crossing("wear", 45)], 45)[0].state == "chattering"
    assert faults.crossings([crossing("joint", 46)], 46)[0].state == "updated"
    # the acknowledged detector after the window, while the fault is still open: it agrees again
    faults.acknowledged([acknowledgement("wear", 47)], 47, latched=["kl_raw", "joint"])
    assert faults.crossings([crossing("wear", 68)], 68)[0].state == "updated"
    assert faults.raised == 1 and faults.chattering == 1


def test_a_maintenance_clears_the_fault_and_no_chatter_window_follows():
    faults = tracker()
    faults.crossings([crossing("wear", 50), crossing("kl_raw", 50)], 50)
    [cleared] = faults.cleared([Alarm(ROBOT, JOINT, 51, q, "cleared") for q in ("wear", "kl_raw")], 51)
    out = valid(cleared)
    assert (out["state"], out["fault"], out["open"], out["statistic"]) == ("cleared", "r1/2/50", False, None)
    assert [d["quantity"] for d in out["detectors"]] == ["wear", "kl_raw"]
    assert faults.cleared([], 52) == []                        # nothing latched: no record
    assert faults.crossings([crossing("wear", 53)], 53)[0].fault == "r1/2/53"


def test_the_open_fault_survives_a_restart_through_json():
    faults = tracker()
    faults.crossings([crossing("wear", 60)], 60)
    saved = json.loads(json.dumps(faults.state_dict()))
    restored = FaultTracker.from_state(AlarmConfig(), ROBOT, JOINT, saved)
    restored.reconcile(["wear"])
    [updated] = restored.crossings([crossing("kl_raw", 64)], 64)
    assert (updated.state, updated.fault, restored.raised) == ("updated", "r1/2/60", 1)
    # the other side: none of its detectors latched any more (they relearn) closes it; a crossing is new
    relearned = FaultTracker.from_state(AlarmConfig(), ROBOT, JOINT, saved)
    relearned.reconcile([])
    assert relearned.crossings([crossing("kl_raw", 64)], 64)[0].state == "raised"


@pytest.mark.parametrize("state", [{"fault": {"id": "x"}}, {"fault": 3}, {"raised": "many"}, [1, 2],
                                   {"fault": {"id": "a", "first": "wear", "evidence": [], "open": True}}])
def test_an_unusable_saved_tracker_starts_fresh(state, caplog):
    with caplog.at_level("WARNING", logger="edge_monitor"):     # whatever level another test left it at
        restored = FaultTracker.from_state(AlarmConfig(), ROBOT, JOINT, state)
    assert restored.fault is None and restored.raised == 0
    assert "saved faults unusable" in caplog.text


def test_latched_detectors_without_a_saved_fault_are_acknowledged_as_one():
    """A state saved before faults were kept: the acknowledgement still makes one record."""
    [ack] = tracker().acknowledged([acknowledgement("wear", 70), acknowledgement("kl_raw", 70)], 70, latched=[])
    assert ack.fault == "r1/2/70" and [d["quantity"] for d in ack.detectors or ()] == ["wear", "kl_raw"]


def test_the_chatter_window_is_configured_in_the_alarms_table():
    assert config_from_mapping({}).alarms == AlarmConfig(20)
    assert config_from_mapping({"alarms": {"chatter_cycles": 0}}).alarms.chatter_cycles == 0
    for bad in (-1, 10**7):
        with pytest.raises(ConfigError, match=r"alarms\.chatter_cycles: must be a whole number of cycles 0 … "):
            config_from_mapping({"alarms": {"chatter_cycles": bad}})
    for bad in (2.5, True):
        with pytest.raises(ConfigError, match=r"alarms\.chatter_cycles: expected an integer"):
            config_from_mapping({"alarms": {"chatter_cycles": bad}})
    with pytest.raises(ConfigError, match=r"alarms\.window"):
        config_from_mapping({"alarms": {"window": 3}})
