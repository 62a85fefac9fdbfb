"""Acknowledging an alarm: the decision layer (DetectorBank), the agent (sinks, persistence across a
restart) and the request payload (validated, size-capped; never a traceback)."""

from __future__ import annotations

import dataclasses
import json
import logging

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from test_agent_pipeline import feed as feed_frames
from test_agent_pipeline import small_config

from edge_monitor.config import AgentConfig, ConfigError, config_from_mapping
from edge_monitor.pipeline.agent import Agent
from edge_monitor.pipeline.detectors import DecisionConfig, DetectorBank
from edge_monitor.pipeline.state_store import StateStore
from edge_monitor.sinks.acknowledge import (
    FIELDS,
    MAX_PAYLOAD_BYTES,
    AcknowledgeConfig,
    AcknowledgeRequest,
    parse_request,
)
from edge_monitor.sinks.control_gate import ControlGate
from edge_monitor.sinks.maintenance import MaintenanceConfig
from protocol.frames import MAX_JOINTS

from synthetic_frames import make_frames

QUANTITIES = ("wear", "kl_raw", "kl_weighted")


def small_bank() -> DetectorBank:
    # 20 learning values: the asymptotic threshold at Pf = 1e-3 (a calibrated one for 10⁴ from 20 values
    # is far higher, and these tests are about acknowledging, not calibrating)
    config = DecisionConfig(n_nominal=20, density="gauss", pf=1e-3, pf_joint=1e-3,
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
        {"schema": 1, "robot": "r1", "joint": 2, "cycle": 65, "utc": None, "quantity": "wear", "state": "acknowledged",
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


# -- the agent: sinks, state file, restart ------------------------------------------------------------


class AlarmSink:
    def __init__(self) -> None:
        self.alarms: list[dict] = []

    def on_symptom(self, symptom) -> None: pass
    def on_alarm(self, alarm) -> None: self.alarms.append(alarm.to_dict())
    def on_health(self, health) -> None: pass
    def close(self) -> None: pass


def test_the_agent_acknowledges_sends_the_event_and_a_restart_does_not_bring_the_alarm_back(tmp_path):
    frames = make_frames(14, joints=(0,), wear=lambda j, c: 0.0 if c < 5 else 60.0, seed=9)
    sink = AlarmSink()
    agent = Agent(small_config(), sinks=[sink], state_store=StateStore(tmp_path))
    feed_frames(agent, frames)
    [raised] = [a for a in sink.alarms if a["state"] == "raised"]          # one fault, however many detectors
    assert "wear" in {d["quantity"] for d in raised["detectors"]}
    with pytest.raises(ValueError, match="joint 3: nothing learned yet"):
        agent.acknowledge(3)
    result = agent.acknowledge(0, ["wear"], by="alice", note="probe knocked the arm")
    event = [a for a in sink.alarms if a["state"] == "acknowledged"]
    assert event == [a.to_dict() for a in result.alarms] and len(event) == 1
    assert [d["quantity"] for d in event[0]["detectors"]] == ["wear"] and event[0]["fault"] == raised["fault"]
    assert event[0]["by"] == "alice" and event[0]["note"] == "probe knocked the arm"
    assert event[0]["cycle"] == 12                     # the last cycle published (cycle 13 is still open)
    assert agent.health().counters["alarms_acknowledged"] == 1
    # the state was saved by the acknowledgement itself (no cycle closed since): a restart keeps it
    restarted = Agent(small_config(), state_store=StateStore(tmp_path))
    saved = restarted.state_dict()["joints"]["0"]
    assert saved["acknowledgements"] == 1 and saved["detectors"]["wear"]["latched"] is None
    still = sorted(q for q in ("kl_raw", "kl_weighted") if agent.joints[0].detectors.detectors[q].alarmed)
    assert still                                   # the other side: what was not acknowledged stays latched
    assert event[0]["open"] is True                # … so the fault stays open
    again = restarted.acknowledge(0)
    [record] = again.alarms                        # one record of the same fault (kept across the restart)
    assert sorted(d["quantity"] for d in record.detectors or ()) == still and "wear" in again.not_latched
    assert record.fault == raised["fault"] and record.open is False


# -- the request payload and the gate ----------------------------------------------------------------

JSON_VALUES = st.recursive(st.none() | st.booleans() | st.integers() | st.floats() | st.text(max_size=80),
                           lambda inner: st.lists(inner, max_size=5) | st.dictionaries(st.text(max_size=12), inner,
                                                                                          max_size=5),
                           max_leaves=20)


@pytest.mark.parametrize("payload, request_", [
    (b"", AcknowledgeRequest()),
    (b"  {}  ", AcknowledgeRequest()),
    (b'{"quantities": ["kl_raw", "wear", "kl_raw"]}', AcknowledgeRequest(("kl_raw", "wear"))),
    ('{"by": "Zoë", "note": "probe knocked the arm"}'.encode(), AcknowledgeRequest(None, "Zoë", "probe knocked the arm")),
    (b'{"quantities": null, "by": null}', AcknowledgeRequest()),
])
def test_valid_payloads(payload, request_):
    assert parse_request(payload) == request_


@pytest.mark.parametrize("payload, message", [
    (b"wear", "not a UTF-8 JSON object"),
    (b"\xff\xfe{}", "not a UTF-8 JSON object"),
    (b'["wear"]', "must be a JSON object, got list"),
    (b'{"quantity": ["wear"]}', "unknown field(s) 'quantity'; known: quantities, by, note"),
    (b'{"quantities": "wear"}', "quantities: expected a non-empty list"),
    (b'{"quantities": []}', "quantities: expected a non-empty list"),
    (b'{"quantities": ["wear", "gearbox"]}', "quantities: unknown 'gearbox'"),
    (b'{"by": ""}', "by: expected a string of 1 … 64 characters"),
    (b'{"by": 7}', "by: expected a string"),
    (b'{"by": "alice\\nWARNING forged"}', "by: control characters are not allowed"),
    (b'{"note": "\\ud800"}', "note: control characters"),
    (b'{"note": "' + b"x" * 501 + b'"}', "note: expected a string of 1 … 500 characters"),
    (b" " * (MAX_PAYLOAD_BYTES + 1), f"at most {MAX_PAYLOAD_BYTES}"),
    (b"[" * 3000 + b"]" * 3000, f"at most {MAX_PAYLOAD_BYTES}"),
    (b"[" * 2000 + b"]" * 2000, "not a UTF-8 JSON object"),        # nested deeper than the parser recurses
])
def test_bad_payloads_are_refused_naming_the_field(payload, message):
    with pytest.raises(ValueError) as info:
        parse_request(payload)
    assert message in str(info.value)


@settings(max_examples=300)
@given(st.binary(max_size=MAX_PAYLOAD_BYTES + 10))
def test_random_bytes_never_raise_anything_but_a_value_error(payload):
    try:
        assert isinstance(parse_request(payload), AcknowledgeRequest)
    except ValueError as exc:
        assert str(exc)


@settings(max_examples=300, suppress_health_check=[HealthCheck.too_slow])   # nested JSON draws: slow on a busy CPU
@given(st.dictionaries(st.sampled_from(FIELDS) | st.text(max_size=8), JSON_VALUES, max_size=4))
def test_random_json_objects_are_parsed_or_refused_with_a_message(data):
    try:
        request = parse_request(json.dumps(data).encode())
    except ValueError as exc:
        assert str(exc) and "\n" not in str(exc)
        return
    assert parse_request(request.to_payload()) == request            # what the CLI puts parses the same


class Sample:
    """A Zenoh sample as the gate reads it (duck typing)."""

    def __init__(self, key: str, payload: bytes) -> None:
        self.key_expr, self.payload, self.attachment, self.source_info = key, payload, None, None


def test_the_acknowledge_gate_refuses_a_bad_payload_without_spending_the_rate_limit(caplog):
    gate = ControlGate("r1", "acknowledge", allow=True, max_per_joint=1, parse=parse_request)
    applied: list[tuple[int, AcknowledgeRequest]] = []
    callback = gate.callback(lambda joint, request: applied.append((joint, request)))

    with caplog.at_level(logging.WARNING, logger="edge_monitor.sinks.acknowledge"):
        for key, payload in (("edge/r1/2/acknowledge", b'{"quantities": ["gearbox"]}'),
                             ("edge/*/2/acknowledge", b""), ("edge/r1/2/maintenance", b""),
                             ("edge/r1/2/acknowledge", b'{"quantities": ["wear"], "by": "alice"}'),
                             ("edge/r1/2/acknowledge", b"")):
            callback(Sample(key, payload))
    assert applied == [(2, AcknowledgeRequest(("wear",), "alice"))]
    assert gate.stats() == {"acknowledge_accepted": 1, "acknowledge_refused_disabled": 0,
                            "acknowledge_refused_bad_key": 2, "acknowledge_refused_unknown_joint": 0,
                            "acknowledge_refused_bad_payload": 1, "acknowledge_refused_rate_limited": 1}
    lines = [r.getMessage() for r in caplog.records]
    assert any("acknowledgement refused for joint 2 (quantities: unknown 'gearbox'" in line for line in lines)
    assert any(line.startswith("acknowledgement ACCEPTED for joint 2") for line in lines)


def test_the_acknowledge_gate_refuses_joints_the_agent_does_not_monitor_and_gives_back_the_rate_limit(caplog):
    """Joint 64 (beyond MAX_JOINTS) is refused at the gate; joint 3, which the agent has not learned, and a
    quantity joint 0 does not watch are refused after all (the agent's ValueError): neither counts as
    accepted nor uses up the joint's rate limit, so the operator's corrected request still gets through."""
    config = small_config()
    agent = Agent(dataclasses.replace(config, decision=dataclasses.replace(config.decision, quantities=("wear",))))
    feed_frames(agent, make_frames(6, joints=(0,), seed=9))
    gate = ControlGate("r1", "acknowledge", allow=True, max_per_joint=1, parse=parse_request)
    acknowledged: list[int] = []

    def acknowledge(joint: int, request: AcknowledgeRequest) -> None:
        agent.acknowledge(joint, request.quantities, by=request.by)
        acknowledged.append(joint)

    callback = gate.callback(acknowledge)
    with caplog.at_level(logging.WARNING, logger="edge_monitor.sinks.acknowledge"):
        for key, payload in (("edge/r1/64/acknowledge", b""), ("edge/r1/3/acknowledge", b""),
                             ("edge/r1/3/acknowledge", b""), ("edge/r1/0/acknowledge", b'{"quantities": ["kl_raw"]}'),
                             ("edge/r1/0/acknowledge", b'{"quantities": ["wear"]}')):
            callback(Sample(key, payload))
    assert acknowledged == [0]
    assert gate.stats() == {"acknowledge_accepted": 1, "acknowledge_refused_disabled": 0,
                            "acknowledge_refused_bad_key": 0, "acknowledge_refused_unknown_joint": 3,
                            "acknowledge_refused_bad_payload": 1, "acknowledge_refused_rate_limited": 0}
    lines = [r.getMessage() for r in caplog.records]
    assert any(f"joint 64: this robot has joints 0 … {MAX_JOINTS - 1}" in line for line in lines)
    assert any("'edge/r1/3/acknowledge' refused after all (joint 3: nothing learned yet" in line for line in lines)
    assert any("'edge/r1/0/acknowledge' refused after all (joint 0: quantity 'kl_raw' is not watched" in line
               for line in lines)


def test_remote_acknowledgements_are_off_by_default_and_configured_in_their_own_table(tmp_path):
    assert AgentConfig().acknowledge == AcknowledgeConfig(remote=False, max_per_joint=4, window_s=600.0)
    config = config_from_mapping({"acknowledge": {"remote": True, "max_per_joint": 2}})
    assert config.acknowledge == AcknowledgeConfig(remote=True, max_per_joint=2)
    assert config.maintenance == MaintenanceConfig()
    with pytest.raises(ConfigError, match=r"acknowledge\.max_per_joint: must be 1 … 1000, got 0"):
        config_from_mapping({"acknowledge": {"max_per_joint": 0}})
    with pytest.raises(ConfigError, match=r"acknowledge\.by: unknown key"):
        config_from_mapping({"acknowledge": {"by": "x"}})
    gate = ControlGate("r1", "acknowledge", parse=parse_request)
    assert gate.decide("edge/r1/0/acknowledge", b"{}").reason == "disabled"


# -- the command line: bad arguments and no agent ----------------------------------------------------


@pytest.mark.parametrize("args, message", [
    (["--robot", "r/1", "--joint", "0"], "--robot: robot name 'r/1'"),
    (["--robot", "r1", "--joint", "8"], "--joint 8: a joint index is 0 … 7"),
    (["--robot", "r1", "--joint", "0", "--quantity", "gearbox"], "invalid choice: 'gearbox'"),
    (["--robot", "r1", "--joint", "0", "--note", "a\nb"], "note: control characters are not allowed"),
    (["--robot", "r1", "--joint", "0", "--timeout", "0"], "--timeout 0: must be > 0"),
    (["--robot", "r1", "--joint", "0", "--tls-ca", "/no/ca.pem"], "TLS CA certificate file '/no/ca.pem' does not exist"),
    (["--robot", "r1", "--joint", "0", "--tls-ca", "{pem}", "--zenoh-connect", "tcp/127.0.0.1:7447"],
     "refusing to downgrade"),
])
def test_bad_arguments_exit_2_naming_the_option(args, message, tmp_path, capsys):
    from edge_monitor.cli import main

    pem = tmp_path / "ca.pem"
    pem.write_text("-----BEGIN CERTIFICATE-----\nx\n-----END CERTIFICATE-----\n")
    try:
        code = main(["acknowledge", *[a.format(pem=pem) for a in args]])
    except SystemExit as exc:                 # argparse's own checks (choices)
        code = exc.code
    assert code == 2 and message in capsys.readouterr().err


def test_no_agent_exits_1_after_the_timeout():
    import subprocess
    import sys

    from edge_monitor.sinks.loopback import free_loopback_port
    done = subprocess.run([sys.executable, "-m", "edge_monitor.cli", "acknowledge", "--robot", "r1", "--joint", "0",
                           "--zenoh-connect", f"tcp/127.0.0.1:{free_loopback_port()}", "--timeout", "1"],
                          capture_output=True, text=True, timeout=120)
    assert done.returncode == 1 and "no agent answered for robot r1 joint 0 within 1 s" in done.stderr
