"""Two detector stages: the thermal settling test on the motor temperature, and the detectors learning
their steady nominal once it says so (warm-up nominal calibrated at the allowance boundary, steady
nominal at the learned nominal; docs/DETECTION.md, "Two stages")."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from edge_monitor.errors import ConfigError
from edge_monitor.pipeline.detectors import HOLD_KEY, SETTLING_KEY, SPANS_KEY, DecisionConfig, DetectorBank
from edge_monitor.pipeline.thermal_settling import SettlingConfig, ThermalSettling
from edge_monitor.stats.sequential_detector import DetectorConfig, SequentialDetector

#: Cycle-mean motor temperature scatter in the simulator [°C] (its per-cycle load heats the motor).
NOISE = 3.0


def warm_up(cycles: int, seed: int = 0, tau: float = 200.0) -> np.ndarray:
    """A first-order warm-up 35 → 63 °C with time constant ``tau`` cycles, plus cycle noise."""
    t = np.arange(cycles)
    return 63.0 - 28.0 * np.exp(-t / tau) + np.random.default_rng(seed).normal(0.0, NOISE, cycles)


def first_settled(values: np.ndarray, config: SettlingConfig | None = None) -> int | None:
    tracker = ThermalSettling(config or SettlingConfig())
    return next((i for i, v in enumerate(values) if tracker.update(float(v))), None)


def test_a_warming_joint_settles_once_its_rise_is_slow_and_not_before() -> None:
    """The test settles when slope + 2 SE ≤ 0.02 °C/cycle; over 240 cycles of 3 °C scatter SE ≈ 0.0028,
    so when the fitted slope ≤ 0.0144. The fit is about the true slope 0.14·e^(−t/200) at the window's
    middle, t − 120, which reaches 0.0144 at t ≈ 575; one SE of the fitted slope is ≈ 39 cycles of that
    decay, so every seed settles within ±3 SE: 458 … 692 cycles."""
    cycles = [first_settled(warm_up(1200, seed)) for seed in range(10)]
    assert all(c is not None and 458 <= c <= 692 for c in cycles), cycles


def test_a_constant_temperature_settles_as_soon_as_the_window_is_full() -> None:
    flat = 40.0 + np.random.default_rng(1).normal(0.0, NOISE, 300)
    assert first_settled(flat) == SettlingConfig().window - 1


def test_settled_holds_through_noise_and_ends_when_the_joint_clearly_warms_again() -> None:
    tracker = ThermalSettling()
    rng = np.random.default_rng(2)
    states = [tracker.update(40.0 + rng.normal(0.0, NOISE)) for _ in range(2000)]
    assert all(states[SettlingConfig().window:])             # 1 760 noisy flat cycles: never flickers
    ramp = [tracker.update(40.0 + 0.3 * i + rng.normal(0.0, NOISE)) for i in range(200)]
    assert not ramp[-1]                                       # 0.3 °C per cycle: warming again


def test_unknown_temperatures_are_skipped() -> None:
    tracker = ThermalSettling()
    for _ in range(500):
        assert tracker.update(None) is False and tracker.update(math.nan) is False
    assert tracker.rate is None


@settings(max_examples=25, deadline=None)
@given(st.lists(st.floats(-40, 150), min_size=0, max_size=300), st.integers(20, 200))
def test_state_round_trip_continues_identically(values: list[float], window: int) -> None:
    config = SettlingConfig(window=window)
    tracker = ThermalSettling(config)
    for v in values:
        tracker.update(v)
    restored = ThermalSettling.from_state(config, json.loads(json.dumps(tracker.state_dict())))
    assert restored.settled == tracker.settled
    for v in (50.0, 51.0, 49.0):
        assert restored.update(v) == tracker.update(v)
        assert restored.rate == pytest.approx(tracker.rate, nan_ok=True)


@pytest.mark.parametrize("kwargs, match", [({"window": 5}, "settling_window"),
                                           ({"max_rate": 0.0}, "settling_max_rate"),
                                           ({"max_rate": True}, "settling_max_rate"),
                                           ({"z": -1.0}, "z")])
def test_bad_settings_are_clear_errors(kwargs: dict, match: str) -> None:
    with pytest.raises(ConfigError, match=match):
        SettlingConfig(**kwargs)


# ---------------------------------------------------------------------- the detector's two stages
def _detector(**kwargs) -> SequentialDetector:
    return SequentialDetector(DetectorConfig(n_nominal=20, steady_nominal=20, window=30, density="gauss",
                                             calibration_draws=16, calibration_steps=400, direction="increase",
                                             allowance=0.75, arl0=100, **kwargs))


def test_a_monitoring_detector_learns_its_steady_nominal_while_still_deciding() -> None:
    """Warm-up nominal N(0, 1) at the boundary; settled at cycle 40; the next 20 values (N(5, 1), a
    warmer joint) are the steady nominal: meanwhile the warm-up threshold still decides (a 5 σ jump
    would alarm it, so it may not see those values), afterwards the detector is steady, calibrated
    for the healthy drift after learning (the default steady_at), and quiet on values like its steady nominal."""
    rng = np.random.default_rng(5)
    det = _detector()
    for i, v in enumerate(rng.normal(size=40)):
        det.update(v, i)
    assert det.stage == "warm-up" and det.calibration_record()["at"] == "boundary"
    det.begin_steady()
    during = [det.update(v, 40 + i) for i, v in enumerate(rng.normal(0.2, 1.0, 19))]
    assert all(d.state == "monitoring" and d.calibration["stage"] == "warm-up" for d in during)
    switched = det.update(0.1, 59)
    assert switched.calibration == {"arl0": 100, "at": "healthy_drift", "stage": "steady",
                                    "method": det.calibration.method, "h_se": det.calibration.h_se}
    assert det.threshold is not None and not det.alarmed
    det.begin_steady()                                         # a no-op once steady
    assert det.stage == "steady" and det._steady_values is None


def test_a_learning_detector_learns_settled_values_only_and_an_alarmed_one_keeps_its_alarm() -> None:
    det = _detector()
    for i in range(10):
        det.update(float(i % 3), i)
    det.begin_steady()
    assert det.stage == "steady" and det._nominal == []       # the 10 warm-up values are dropped
    alarmed = _detector()
    rng = np.random.default_rng(6)
    for i, v in enumerate(np.concatenate([rng.normal(size=20), rng.normal(8.0, 1.0, 20)])):
        alarmed.update(v, i)
    assert alarmed.alarmed
    alarmed.begin_steady()
    assert alarmed.stage == "warm-up" and alarmed._steady_values is None
    alarmed.reset()                                            # maintenance: warm-up again
    assert alarmed.stage == "warm-up" and not alarmed.alarmed


def test_a_detector_saved_while_learning_its_steady_nominal_continues_identically() -> None:
    rng = np.random.default_rng(7)
    values = rng.normal(size=80)
    det = _detector()
    for i, v in enumerate(values[:30]):
        det.update(v, i)
    det.begin_steady()
    for i, v in enumerate(values[30:40]):
        det.update(v, 30 + i)
    restored = SequentialDetector.from_state(det.config, json.loads(json.dumps(det.state_dict())))
    assert restored.stage == "warm-up" and restored._steady_values == det._steady_values
    for i, v in enumerate(values[40:]):
        assert restored.update(v, 40 + i) == det.update(v, 40 + i)
    assert restored.stage == det.stage == "steady"


def test_the_bank_starts_the_steady_stage_of_every_detector_when_the_joint_settles() -> None:
    """A bank fed 60 learning values while its joint warms, then a flat temperature: once the test
    settles every detector learns again and ends steady (a detector that alarms on these random values
    is reset, as by a maintenance, and then learns its steady nominal directly); its state keeps the
    temperature history."""
    config = DecisionConfig(n_nominal=20, steady_nominal=30, density="gauss", density_joint="gauss",
                            calibration_draws=16, calibration_steps=400, settling_window=40)
    bank = DetectorBank(config, {})
    rng = np.random.default_rng(8)
    temperature = np.concatenate([np.linspace(30, 50, 60), np.full(200, 50.0)]) + rng.normal(0, NOISE, 260)
    settled_at = None
    for cycle, t in enumerate(temperature):
        bank.observe_temperature(float(t))
        values = {"wear_score": rng.normal(), "kl_raw": float(np.exp(rng.normal(-3, 0.3))),
                  "kl_weighted": float(np.exp(rng.normal(-4, 0.3)))}
        decisions, _ = bank.update(values, "r", 0, cycle)
        for quantity, decision in decisions.items():
            if decision.alarm:
                bank.detectors[quantity].reset()
        if settled_at is None and bank.settling.settled:
            settled_at = cycle
    assert settled_at is not None and settled_at >= 60
    assert {d.stage for d in bank.detectors.values()} == {"steady"}
    assert {d.calibration["at"] for d in decisions.values()} == {"healthy_drift"}   # the agent's steady default
    state = json.loads(json.dumps(bank.state_dict()))
    assert state[SETTLING_KEY]["settled"] is True
    restored = DetectorBank(config, {})
    restored.load_state(state, 0)
    assert restored.settling.settled and restored.detectors["wear"].stage == "steady"


def test_steady_relearn_off_keeps_the_warm_up_nominal() -> None:
    bank = DetectorBank(DecisionConfig(steady_relearn=False, settling_window=20), {})
    for _ in range(50):
        bank.observe_temperature(40.0)
    assert bank.settling.settled and {d.stage for d in bank.detectors.values()} == {"warm-up"}
    with pytest.raises(ConfigError, match="steady_calibrate_at"):
        DecisionConfig(steady_calibrate_at="somewhere")


def test_an_acknowledged_alarm_restarts_the_statistic_on_the_same_nominal() -> None:
    rng = np.random.default_rng(9)
    det = _detector()
    for i, v in enumerate(np.concatenate([rng.normal(size=20), rng.normal(8.0, 1.0, 5)])):
        det.update(v, i)
    assert det.alarmed
    threshold, density = det.threshold, det.density
    det.acknowledge()
    after = det.update(0.0, 25)
    assert not det.alarmed and not after.alarm and after.statistic == pytest.approx(0.0, abs=1e-9)
    assert det.threshold == threshold and det.density is density


@pytest.mark.parametrize("state", [{}, {"recent": None}, {"recent": "abc"}, {"recent": [1e308, "x", None, True]},
                                   {"recent": {"a": 1}, "settled": "yes"}, {"recent": [], "settled": True},
                                   {"recent": [40.0] * 50, "settled": True}])
def test_a_damaged_saved_history_is_dropped_not_trusted(state: dict) -> None:
    tracker = ThermalSettling.from_state(SettlingConfig(), state)
    assert tracker.settled is False and tracker.update(40.0) is False


def test_a_saved_state_is_a_snapshot_and_damaged_steady_values_are_rejected() -> None:
    det = _detector()
    rng = np.random.default_rng(10)
    for i, v in enumerate(rng.normal(size=25)):
        det.update(v, i)
    det.begin_steady()
    det.update(0.1, 25)
    snapshot = det.state_dict()
    det.update(0.2, 26)
    assert len(snapshot["steady_values"]) == 1                     # not the live list
    for damaged in ([[0.1, 0.2]], [[math.nan]], [[0.0]] * 20):      # wrong size, not finite, too many
        state = json.loads(json.dumps({**snapshot, "steady_values": damaged}))
        with pytest.raises(ValueError, match="steady values"):
            SequentialDetector.from_state(det.config, state)


def test_warming_again_drops_a_steady_collection_under_way() -> None:
    config = DecisionConfig(n_nominal=20, steady_nominal=100, density="gauss", density_joint="gauss",
                            calibration_draws=16, calibration_steps=400, settling_window=40)
    bank = DetectorBank(config, {})
    rng = np.random.default_rng(11)
    for cycle in range(80):
        bank.observe_temperature(40.0 + rng.normal(0, 0.5))
        bank.update({"wear_score": rng.normal(), "kl_raw": 0.05, "kl_weighted": 0.02}, "r", 0, cycle)
    assert bank.settling.settled and bank.detectors["wear"]._steady_values
    for cycle in range(80, 140):                                     # 1 °C per cycle: clearly warming
        bank.observe_temperature(40.0 + (cycle - 79) + rng.normal(0, 0.5))
    assert not bank.settling.settled and bank.detectors["wear"]._steady_values is None
    assert bank.detectors["wear"].stage == "warm-up"


def test_maintenance_forgets_the_temperature_history_and_keep_keeps_the_schedule() -> None:
    from edge_monitor.pipeline.agent_config import AgentConfig
    from edge_monitor.pipeline.joint_monitor import JointMonitor

    monitor = JointMonitor(0, AgentConfig())
    for _ in range(300):
        monitor.detectors.observe_temperature(45.0)
    assert monitor.detectors.settling.settled
    monitor.declare_maintenance(cycle=300)
    assert not monitor.detectors.settling.settled                 # the joint may have cooled meanwhile
    mine = AgentConfig(decision=DecisionConfig(steady_relearn=False, settling_window=60))
    saved = AgentConfig(decision=DecisionConfig(allowance=0.5)).fingerprint(0)
    kept, names = mine.with_learned(0, saved)
    assert names == ["decision"] and kept.decision.allowance == 0.5
    assert kept.decision.steady_relearn is False and kept.decision.settling_window == 60


def test_keep_takes_the_current_calibration_settings_and_an_old_state_s_still_match() -> None:
    """Where a calibration simulates (the point, the drifts, the wander) is not learned: a state saved with
    other calibration settings, or by a version whose fingerprint still named them (before
    ``steady_drift_joint`` existed), matches the current config; "keep" keeps nothing and the thresholds
    are re-derived for the current settings (``SequentialDetector.from_state``)."""
    from edge_monitor.pipeline.agent_config import AgentConfig

    old_drift = {"wear_score": (0.0, 0.2), "kl_raw": (0.3, 0.1), "kl_weighted": (0.2, 0.1)}
    saved = AgentConfig(decision=DecisionConfig(steady_drift=old_drift, calibrate_at="healthy_drift")).fingerprint(0)
    assert saved == AgentConfig().fingerprint(0)
    saved["decision"].update(steady_drift={q: list(v) for q, v in old_drift.items()}, steady_calibrate_at="nominal",
                             calibrate_at="healthy_drift", healthy_drift={"kl_raw": [0.3, 0.2]})   # an older file
    kept, names = AgentConfig().with_learned(0, saved)
    assert names == [] and kept == AgentConfig()
    saved["decision"]["allowance"] = 0.5                     # a learned setting: kept, with the current drifts
    kept, names = AgentConfig().with_learned(0, saved)
    assert names == ["decision"] and kept.decision.allowance == 0.5
    assert kept.decision.steady_drift == DecisionConfig().steady_drift
    assert kept.decision.steady_drift_joint == DecisionConfig().steady_drift_joint


def _old_decision_fingerprint(config: DecisionConfig) -> dict:
    """A decision fingerprint as the versions before 2026-11-28 saved it (their rule, verbatim)."""
    from dataclasses import asdict

    from edge_monitor.pipeline.decision_config import SCHEDULE_KEYS
    from edge_monitor.stats.detector_config import STEADY_DEFAULTS

    out = {**asdict(config), "quantities": list(config.quantities), "warm_up_hold": list(config.warm_up_hold),
           "healthy_drift": {q: list(v) for q, v in sorted(config.healthy_drift.items())},
           "steady_drift": {q: list(v) for q, v in sorted(config.steady_drift.items())},
           "steady_drift_joint": {q: list(v) for q, v in sorted(config.steady_drift_joint.items())},
           "steady_wander": dict(sorted(config.steady_wander.items()))}
    if config.calibrate_at == "boundary":
        del out["calibrate_at"], out["healthy_drift"]
    steady = ("steady_calibrate_at", "steady_nominal", "steady_density", "steady_transform", "steady_simulate_from")
    if tuple(out[key] for key in steady) == STEADY_DEFAULTS:
        for key in steady:
            del out[key]
    for key in SCHEDULE_KEYS:
        del out[key]
    return json.loads(json.dumps(out))


@pytest.mark.parametrize("changes", [{}, {"steady_calibrate_at": "boundary"}, {"calibrate_at": "healthy_drift"}])
def test_keep_finds_nothing_to_keep_in_an_older_versions_fingerprint_of_the_same_settings(changes: dict) -> None:
    """An older version's decision fingerprint of the same settings (calibration settings in it, the steady
    group kept where only the calibration point differed) compares equal: "keep" keeps nothing; a damaged
    decision section is skipped (the detectors then relearn alone), not the joint's other models."""
    import dataclasses

    from edge_monitor.pipeline.agent_config import AgentConfig

    mine = AgentConfig(decision=dataclasses.replace(DecisionConfig(), **changes))
    saved = {**mine.fingerprint(0), "decision": _old_decision_fingerprint(mine.decision)}
    assert mine.with_learned(0, saved) == (mine, [])
    assert mine.with_learned(0, {**saved, "decision": ["damaged"]}) == (mine, [])


# ------------------------------------------------ a restart after a stop: colder than the steady nominal
#: The hold option (``decision.warm_up_hold`` names the quantities that hold outside their temperature span
#: instead of testing with the temperature slack, tests/test_temperature_slack.py): all four, no slack.
HOLD = {"warm_up_hold": ("wear", "kl_raw", "kl_weighted", "joint"),
        "temperature_slack": {"wear_score": (0.0, 0.0), "kl_raw": (0.0, 0.0), "kl_weighted": (0.0, 0.0)}}


def _steady_bank(seed: int, **settings) -> tuple[DetectorBank, np.random.Generator, int]:
    """A bank whose detectors are all steady, learned at 50 ± 3 °C (the wear score N(0, 1), the logs of
    the KL distances N(−3, 0.3) and N(−4, 0.3)); returns it, its generator and the next cycle."""
    config = DecisionConfig(n_nominal=20, steady_nominal=30, density="gauss", density_joint="gauss",
                            calibration_draws=16, calibration_steps=400, settling_window=40, arl0_cycles=1000,
                            **settings)
    bank = DetectorBank(config, {})
    rng = np.random.default_rng(seed)
    cycle = 0
    while {d.stage for d in bank.detectors.values()} != {"steady"} or bank.collecting:
        bank.observe_temperature(50.0 + rng.normal(0.0, NOISE))
        decisions, _ = bank.update(_healthy(rng), "r", 0, cycle)
        for quantity, decision in decisions.items():
            if decision.alarm:
                bank.detectors[quantity].reset()
        cycle += 1
        assert cycle < 1000
    return bank, rng, cycle


def _healthy(rng: np.random.Generator, kl_shift: float = 0.0) -> dict[str, float]:
    """One cycle's detector inputs; ``kl_shift``: the log KL distances ``kl_shift`` (their σ: 0.3) up."""
    return {"wear_score": rng.normal(), "kl_raw": float(np.exp(rng.normal(-3.0 + 0.3 * kl_shift, 0.3))),
            "kl_weighted": float(np.exp(rng.normal(-4.0 + 0.3 * kl_shift, 0.3)))}


def test_a_steady_detector_holds_while_the_joint_is_colder_than_it_learned_and_resumes_when_warm() -> None:
    """After a stop the joint restarts at 30 °C, 20 °C below the span its steady nominals were learned in,
    and its KL distances sit 6 σ up (what a cold joint's do): the steady detectors hold — no statistic,
    no alarm, the reason says why — while the joint is colder than those spans. Other side: the same 6 σ
    once the joint is back at 50 °C raises the KL alarms within a few cycles (the hold masks nothing
    in range); a joint colder by less than the margin (2 °C) is watched; without a temperature no hold. (The
    hold option, ``decision.warm_up_hold``.)"""
    bank, rng, cycle = _steady_bank(10, **HOLD)
    spans = dict(bank.spans.learned)
    assert set(spans) == set(bank.detectors) and all(38.0 < span.lo <= span.hi < 62.0 for span in spans.values())
    for k in range(40):
        bank.observe_temperature(30.0 + 0.2 * k)
        decisions, alarms = bank.update(_healthy(rng, kl_shift=6.0), "r", 0, cycle + k)
        assert not alarms and all(d.statistic is None and d.reason.startswith("held: motor temperature")
                                  for d in decisions.values())
    cycle += 40
    low = min(span.lo for span in spans.values())
    bank.observe_temperature(low - 1.0)
    decisions, _ = bank.update(_healthy(rng), "r", 0, cycle)
    assert all(d.statistic is not None for d in decisions.values())       # inside the margin: watched
    bank.observe_temperature(None)
    decisions, _ = bank.update(_healthy(rng), "r", 0, cycle + 1)
    assert all(d.statistic is not None for d in decisions.values())       # unknown: watched
    raised: list[str] = []
    for k in range(2, 30):
        bank.observe_temperature(50.0 + rng.normal(0.0, NOISE))
        raised += [a.quantity for a in bank.update(_healthy(rng, kl_shift=6.0), "r", 0, cycle + k)[1]]
    assert {"kl_raw", "kl_weighted"} <= set(raised)


def test_the_learned_spans_survive_a_restart_and_a_maintenance_clears_them() -> None:
    """Saved with the detectors (strict JSON: no infinities while a span is still empty), restored as
    they were; a damaged span is dropped (that detector does not hold); a declared maintenance clears
    them, as it makes every detector learn again."""
    bank, rng, cycle = _steady_bank(11)
    state = json.loads(json.dumps(bank.state_dict(), allow_nan=False))
    restored = DetectorBank(bank.config, {})
    restored.load_state(state, 0)
    assert restored.spans.learned == bank.spans.learned and restored.spans.learned
    state[SPANS_KEY]["learned"]["wear"] = [60.0, "hot"]
    damaged = DetectorBank(bank.config, {})
    damaged.load_state(state, 0)
    assert "wear" not in damaged.spans.learned and "kl_raw" in damaged.spans.learned
    bank.reset("r", 0, cycle)
    assert bank.spans.learned == {}
    fresh = DetectorBank(bank.config, {})
    fresh.observe_temperature(50.0)
    fresh.update(_healthy(rng), "r", 0, 0)
    json.dumps(fresh.state_dict(), allow_nan=False)


def _collecting_steady_bank(seed: int) -> tuple[DetectorBank, np.random.Generator, int]:
    """A bank settled at 50 ± 3 °C whose detectors have begun collecting their steady values (60 of them);
    returns it, its generator and the next cycle."""
    config = DecisionConfig(n_nominal=20, steady_nominal=60, density="gauss", density_joint="gauss",
                            calibration_draws=16, calibration_steps=400, settling_window=40, arl0_cycles=1000)
    bank = DetectorBank(config, {})
    rng = np.random.default_rng(seed)
    cycle = 0
    while not bank.detectors["wear"]._steady_values:
        bank.observe_temperature(50.0 + rng.normal(0.0, NOISE))
        bank.update(_healthy(rng), "r", 0, cycle)
        cycle += 1
    return bank, rng, cycle


def test_a_stop_restarts_the_settling_so_no_steady_nominal_spans_it() -> None:
    """A settled joint collecting its steady values (50 ± 3 °C) stops overnight and restarts at 30 °C. A
    regression over a window that holds the warm cycles and the cold restart sees no warming, so before
    the stop was noticed the collection went on across it and the steady nominal mixed warm and cold
    cycles (seed 401 of the plant week: a span of 34–65 °C, then no cold-restart hold and two false
    alarms at the next restart). Now the stop restarts the settling test: the collection under way is
    dropped, and the steady nominals learned once the joint has settled again hold warm cycles only."""
    bank, rng, cycle = _collecting_steady_bank(12)
    assert bank.settling.settled and bank.detectors["wear"].stage == "warm-up"
    for k in range(2):
        bank.observe_temperature(30.0 + rng.normal(0.0, NOISE))
        bank.update(_healthy(rng), "r", 0, cycle + k)
    assert bank.hold_temperature.stops == 1 and not bank.settling.settled
    assert all(d._steady_values is None for d in bank.detectors.values())
    cycle += 2
    temperature = 50.0 - 20.0 * np.exp(-np.arange(600) / 30.0)      # warming again towards 50 °C
    for k, t in enumerate(temperature + rng.normal(0.0, NOISE, temperature.size)):
        bank.observe_temperature(float(t))
        decisions, _ = bank.update(_healthy(rng), "r", 0, cycle + k)
        for quantity, decision in decisions.items():
            if decision.alarm:
                bank.detectors[quantity].reset()
    assert {d.stage for d in bank.detectors.values()} == {"steady"}
    assert all(span.lo > 44.0 for span in bank.spans.learned.values()), bank.spans.learned


def test_a_state_saved_before_the_smoothing_still_sees_the_first_stop() -> None:
    """An agent upgraded across an overnight stop: its saved bank has no smoothing state, which is then
    replayed from the settling test's recent temperatures, so the stop right after the restart is still
    counted, the settling restarts and the steady collection under way is dropped (a fresh smoothing would
    need 32 readings before it could see a jump)."""
    bank, rng, cycle = _collecting_steady_bank(13)
    config = bank.config
    state = json.loads(json.dumps(bank.state_dict()))
    del state[HOLD_KEY]
    restored = DetectorBank(config, {})
    restored.load_state(state, 0)
    assert restored.settling.settled and restored.detectors["wear"]._steady_values
    for k, t in enumerate((30.0, 31.0)):
        restored.observe_temperature(t)
        restored.update(_healthy(rng), "r", 0, cycle + k)
    assert restored.hold_temperature.stops == 1 and not restored.settling.settled
    assert all(d._steady_values is None for d in restored.detectors.values())


def test_an_acknowledged_alarm_keeps_the_steady_values_collected_before_it() -> None:
    """A settled joint collecting its steady values (60) raises a warm-up alarm on a glitch run, which an operator
    judges false: the values collected before the alarm stay, none are added while it is latched, and the
    collection goes on after the acknowledgement to a steady nominal. (It was dropped: with warm-up false alarms
    at their stated rate a short target never reached its steady stage.) The other side: the detector whose
    alarm is not acknowledged collects nothing more while latched."""
    bank, rng, cycle = _collecting_steady_bank(13)
    wear = bank.detectors["wear"]
    collected = len(wear._steady_values or [])
    assert collected >= 1
    while not wear.alarmed:
        bank.observe_temperature(50.0 + rng.normal(0.0, NOISE))
        bank.update({**_healthy(rng), "wear_score": 12.0}, "r", 0, cycle)
        cycle += 1
        collected += 1                                   # the alarm's own value too: collected before the test
    latched = len(wear._steady_values or [])
    for _ in range(5):                                   # latched: nothing is collected
        bank.observe_temperature(50.0 + rng.normal(0.0, NOISE))
        bank.update(_healthy(rng), "r", 0, cycle)
        cycle += 1
    assert len(wear._steady_values or []) == latched == collected
    bank.acknowledge("r", 0, cycle, ["wear"])
    assert len(wear._steady_values or []) == latched and not wear.alarmed
    while wear.stage != "steady":
        bank.observe_temperature(50.0 + rng.normal(0.0, NOISE))
        bank.update(_healthy(rng), "r", 0, cycle)
        cycle += 1
        assert cycle < 500
    assert wear.state == "monitoring" and wear.fits == 2
