"""The warm-up hold, the option (``decision.warm_up_hold``, default off: the temperature slack watches instead,
tests/test_temperature_slack.py): the detectors of the quantities it names (here the KL distances and the
joint vector) skip the cycles warmer than the span their warm-up nominal was learned in, until the steady
stage replaces it; the wear evidence watches on (docs/DETECTION.md, "Operating conditions"). Both sides: what
the hold keeps quiet, and that it masks nothing it should not."""

from __future__ import annotations

import json
from types import SimpleNamespace

import numpy as np
import pytest

from edge_monitor.errors import ConfigError
from edge_monitor.pipeline.detectors import OLD_SPANS_KEY, SETTLING_KEY, SPANS_KEY, DecisionConfig, DetectorBank
from edge_monitor.pipeline.nominal_temperature import NominalSpans
from edge_monitor.pipeline.operating_range import Span

#: Cycle-mean motor temperature scatter in the simulator [°C].
NOISE = 3.0
#: Where the warm-up nominals are learned [°C] (a cold joint).
COLD = 35.0
HELD = {"kl_raw", "kl_weighted", "joint"}
#: The option under test: these detectors hold, and test with no temperature slack.
HOLD = {"warm_up_hold": ("kl_raw", "kl_weighted", "joint"),
        "temperature_slack": {"wear_score": (0.0, 0.0), "kl_raw": (0.0, 0.0), "kl_weighted": (0.0, 0.0)}}


def _inputs(rng: np.random.Generator, kl_shift: float = 0.0, wear_shift: float = 0.0) -> dict[str, float]:
    """One cycle's detector inputs: the wear score N(``wear_shift``, 1), the logs of the KL distances
    N(−3, 0.3) and N(−4, 0.3) moved ``kl_shift`` of their σ up."""
    return {"wear_score": rng.normal(wear_shift, 1.0),
            "kl_raw": float(np.exp(rng.normal(-3.0 + 0.3 * kl_shift, 0.3))),
            "kl_weighted": float(np.exp(rng.normal(-4.0 + 0.3 * kl_shift, 0.3)))}


def _warm_up_bank(seed: int, **settings) -> tuple[DetectorBank, np.random.Generator, int]:
    """A bank whose detectors have learned their warm-up nominals at 35 ± 3 °C and are monitoring; the
    settling window (1 000 cycles) keeps them in the warm-up stage for the test."""
    config = DecisionConfig(n_nominal=20, density="gauss", density_joint="gauss", calibration_draws=16,
                            calibration_steps=400, settling_window=1000, arl0_cycles=1000, **{**HOLD, **settings})
    bank = DetectorBank(config, {})
    rng = np.random.default_rng(seed)
    cycle = 0
    while bank.collecting:
        bank.observe_temperature(COLD + rng.normal(0.0, NOISE))
        bank.update(_inputs(rng), "r", 0, cycle)
        cycle += 1
    return bank, rng, cycle


def _run(bank: DetectorBank, rng: np.random.Generator, cycle: int, temperature: float | None, cycles: int,
         **shift: float) -> tuple[list, set[str]]:
    """``cycles`` cycles at ``temperature`` (plus scatter) with the inputs shifted by ``shift``: every
    cycle's decisions and the quantities that raised an alarm."""
    decisions, raised = [], set()
    for k in range(cycles):
        bank.observe_temperature(None if temperature is None else temperature + rng.normal(0.0, NOISE))
        d, alarms = bank.update(_inputs(rng, **shift), "r", 0, cycle + k)
        decisions.append(d)
        raised |= {a.quantity for a in alarms}
    return decisions, raised


def test_a_warming_joint_holds_its_kl_and_joint_detectors_and_its_wear_evidence_watches_on() -> None:
    """The joint warms to 60 °C, 25 °C above where its warm-up nominals were learned, and its KL distances
    drift 6 σ up (far more than a healthy joint's ≈ 1 σ, docs/DETECTION.md): the KL and joint-vector
    detectors hold — no statistic, no alarm, the reason says why; the wear detector decides every cycle.
    Other side: a 6 σ wear shift meanwhile raises the wear alarm. Every held cycle is counted."""
    bank, rng, cycle = _warm_up_bank(1)
    assert {q: bank.detectors[q].stage for q in bank.detectors} == dict.fromkeys(bank.detectors, "warm-up")
    assert all(COLD - 4 * NOISE < s.lo <= s.hi < COLD + 4 * NOISE for s in bank.spans.learned.values())
    _run(bank, rng, cycle, COLD + 25.0, 10)         # the smoothing follows the warming (a few cycles)
    cycle += 10
    decisions, raised = _run(bank, rng, cycle, COLD + 25.0, 40, kl_shift=6.0)
    assert not raised
    for d in decisions:
        assert all(d[q].statistic is None and "above" in d[q].reason and d[q].reason.startswith("held")
                   for q in HELD)
        assert d["wear"].statistic is not None
    _, raised = _run(bank, rng, cycle + 40, COLD + 25.0, 30, kl_shift=6.0, wear_shift=6.0)
    assert raised == {"wear"}
    assert all(bank.held[q] >= 70 for q in HELD) and set(bank.held) == HELD       # counted for the health record


def test_the_hold_masks_nothing_in_range_nor_when_switched_off_or_the_temperature_is_unknown() -> None:
    """The same 6 σ KL shift raises the KL alarms (a) within the learned span, (b) warm with
    ``warm_up_hold = []`` and (c) without a temperature signal: the hold, not the detectors, kept the
    warm joint quiet above, and only where the temperature says the joint left its span."""
    for temperature, settings in ((COLD, {}), (COLD + 25.0, {"warm_up_hold": ()}), (None, {})):
        bank, rng, cycle = _warm_up_bank(2, **settings)
        _, raised = _run(bank, rng, cycle, temperature, 30, kl_shift=6.0)
        assert {"kl_raw", "kl_weighted", "joint"} <= raised, (temperature, settings, raised)


def test_held_detectors_still_learn_their_steady_nominal_from_the_settled_joint() -> None:
    """A joint that warms 35 → 60 °C and settles there: its held detectors collect the settled values,
    learn their steady nominals (their spans now around 60 °C) and decide again; the wear detector's
    nominal is learned the same way."""
    config = DecisionConfig(n_nominal=20, steady_nominal=30, density="gauss", density_joint="gauss",
                            calibration_draws=16, calibration_steps=400, settling_window=40, arl0_cycles=1000,
                            **HOLD)
    bank = DetectorBank(config, {})
    rng = np.random.default_rng(3)
    temperature = np.concatenate([np.full(20, COLD), np.linspace(COLD, 60.0, 60), np.full(200, 60.0)])
    held = 0
    for cycle, t in enumerate(temperature + rng.normal(0.0, NOISE, temperature.size)):
        bank.observe_temperature(float(t))
        decisions, _ = bank.update(_inputs(rng), "r", 0, cycle)
        held += sum(d.reason.startswith("held") for d in decisions.values())
        for quantity, decision in decisions.items():
            if decision.alarm:
                bank.detectors[quantity].reset()
    assert held > 0
    assert {d.stage for d in bank.detectors.values()} == {"steady"} and not bank.collecting
    assert all(60.0 - 4 * NOISE < s.lo <= s.hi < 60.0 + 4 * NOISE for s in bank.spans.learned.values())
    assert all(d.statistic is not None for d in decisions.values())


def test_the_spans_of_a_state_saved_before_the_warm_up_kept_them_are_read() -> None:
    """A state saved under the former key (steady spans only) restores those spans; the setting is
    checked like every other."""
    bank, rng, cycle = _warm_up_bank(4)
    state = json.loads(json.dumps(bank.state_dict(), allow_nan=False))
    state[OLD_SPANS_KEY] = state.pop(SPANS_KEY)
    restored = DetectorBank(bank.config, {})
    restored.load_state(state, 0)
    assert restored.spans.learned == bank.spans.learned and restored.spans.warm_up_hold == HELD
    with pytest.raises(ConfigError, match="warm_up_hold"):
        DecisionConfig(warm_up_hold=("kl_rwa",))


def test_an_alarm_during_the_steady_collection_keeps_the_warm_up_span_and_the_hold() -> None:
    """The joint settles and the detectors start collecting their steady values while still deciding on
    the warm-up nominal; a 6 σ KL shift then latches an alarm, which ends that collection. The detector
    is still on its warm-up nominal, so its span stays the warm-up one and, once acknowledged, it holds
    again when the joint is warm (it must not treat the ended collection as a new nominal)."""
    bank, rng, cycle = _warm_up_bank(5)
    learned = dict(bank.spans.learned)
    for detector in bank.detectors.values():
        detector.begin_steady()
    _, raised = _run(bank, rng, cycle, COLD, 30, kl_shift=6.0)
    assert {"kl_raw", "kl_weighted"} <= raised
    assert all(bank.detectors[q].stage == "warm-up" for q in raised)
    assert {q: bank.spans.learned[q] for q in raised} == {q: learned[q] for q in raised}
    bank.acknowledge("r", 0, cycle + 30)
    decisions, raised = _run(bank, rng, cycle + 31, COLD + 25.0, 10, kl_shift=6.0)
    assert not raised and all(d["kl_raw"].reason.startswith("held") for d in decisions)


def test_without_the_steady_stage_nothing_holds_while_warm() -> None:
    """``steady_relearn = false``: the warm-up nominal is the only one, and the steady stage that would
    end a hold never comes, so the warm-up detectors do not hold (a 6 σ KL shift on the warm joint
    alarms); a detector whose saved state is not usable learns again without its old span."""
    bank, rng, cycle = _warm_up_bank(6, steady_relearn=False)
    _, raised = _run(bank, rng, cycle, COLD + 25.0, 30, kl_shift=6.0)
    assert {"kl_raw", "kl_weighted", "joint"} <= raised
    state = json.loads(json.dumps(bank.state_dict(), allow_nan=False))
    del state["kl_raw"]
    restored = DetectorBank(bank.config, {})
    restored.load_state(state, 0)
    assert "kl_raw" not in restored.spans.learned and "kl_weighted" in restored.spans.learned


def test_a_joint_without_motor_temperature_is_followed_by_its_lubricant_temperature() -> None:
    """A controller that sends no motor temperature (a foreign DBC): the joint's detectors follow the
    lubricant temperature the wear estimate reads from the friction curve with the joint's own model (none
    while that model is learned; both holds and the settling use it), and a hold says so. The two temperatures differ by the joint's offset,
    so they never mix: after a motor temperature a cycle without one has none, and the first motor
    temperature after friction-read ones restarts the history (settling, spans)."""
    from edge_monitor.config import config_from_mapping
    from edge_monitor.pipeline.joint_monitor import JointMonitor
    from edge_monitor.pipeline.nominal_temperature import FRICTION_TEMPERATURE, MOTOR_TEMPERATURE

    learning = JointMonitor(0, config_from_mapping({}))
    assert not learning.model_ready
    assert learning.joint_temperature(SimpleNamespace(motor_temperature=None), {"temperature": 41.5}) == \
        (None, FRICTION_TEMPERATURE)

    config = config_from_mapping({"model": {"enabled": False}})
    monitor = JointMonitor(0, config)
    read = {"temperature": 41.5}
    assert monitor.joint_temperature(SimpleNamespace(motor_temperature=None), read) == (41.5, FRICTION_TEMPERATURE)
    assert monitor.joint_temperature(SimpleNamespace(motor_temperature=None), {}) == (None, FRICTION_TEMPERATURE)
    for _ in range(300):               # the friction-read history: the settling window fills, a span is learned
        monitor.detectors.observe_temperature(41.5, FRICTION_TEMPERATURE)
    monitor.detectors.spans.learned["kl_raw"] = Span(40.0, 43.0)
    assert monitor.detectors.settling.rate is not None
    assert monitor.joint_temperature(SimpleNamespace(motor_temperature=50.0), read) == (50.0, MOTOR_TEMPERATURE)
    assert monitor.detectors.settling.rate is None and not monitor.detectors.spans.learned
    assert monitor.joint_temperature(SimpleNamespace(motor_temperature=None), read) == (None, MOTOR_TEMPERATURE)
    restored = JointMonitor.from_state(0, config, json.loads(json.dumps(monitor.state_dict())))
    assert restored.joint_temperature(SimpleNamespace(motor_temperature=None), read) == (None, MOTOR_TEMPERATURE)
    old = json.loads(json.dumps(monitor.state_dict()))          # saved before the sources were kept:
    del old["motor_temperature_seen"], old["friction_temperature_used"]
    old["detectors"][SETTLING_KEY]["count"] = 0                 # its settling never saw a motor temperature
    assert JointMonitor.from_state(0, config, old).joint_temperature(
        SimpleNamespace(motor_temperature=None), read) == (41.5, FRICTION_TEMPERATURE)
    old["detectors"][SETTLING_KEY]["count"] = 12                # it did
    assert JointMonitor.from_state(0, config, old).joint_temperature(
        SimpleNamespace(motor_temperature=None), read) == (None, MOTOR_TEMPERATURE)

    # The holds name what the temperature is.
    spans = NominalSpans({"kl_raw": Span(50.0, 55.0)}, warm_up_hold=("kl_raw",))
    steady, warm_up = (SimpleNamespace(state="monitoring", stage=stage) for stage in ("steady", "warm-up"))
    assert spans.held("kl_raw", steady, 40.0, FRICTION_TEMPERATURE).startswith(
        f"held: {FRICTION_TEMPERATURE} 40.0 °C (smoothed) below")
    assert spans.held("kl_raw", warm_up, 70.0, FRICTION_TEMPERATURE).startswith(
        f"held: {FRICTION_TEMPERATURE} 70.0 °C (smoothed) above")
    assert spans.held("kl_raw", warm_up, 70.0, MOTOR_TEMPERATURE).startswith(
        "held: motor temperature 70.0 °C (smoothed) above")
    assert spans.held("kl_raw", warm_up, 56.0, FRICTION_TEMPERATURE) == ""      # within the margin (2 °C)


def test_a_robot_without_motor_temperature_runs_end_to_end_on_its_friction_temperature() -> None:
    """The agent on the simulator's fast path with every motor temperature removed (2 joints, 60 cycles):
    no cycle fails; after the joint's model is learned its detectors' temperature is the friction's, a
    lubricant temperature near the simulator's true one (measured over 78 joint-cycles: error −0.5 ± 1.0 °C,
    at most 2.9 °C; bound: 3 × 2.5 °C, three of ξ̂'s largest std on a warm healthy joint)."""
    from dataclasses import replace

    from edge_monitor.config import config_from_mapping
    from edge_monitor.offline.fast_path import CycleFeeder
    from edge_monitor.pipeline.agent import Agent
    from edge_monitor.pipeline.nominal_temperature import FRICTION_TEMPERATURE
    from sim_controller.config import SimConfig
    from sim_controller.cycle_mode import cycle_signals

    agent = Agent(config_from_mapping({}))
    feeder = CycleFeeder(agent)
    seen: list[tuple[float, float]] = []
    truth: dict[tuple[int, int], float] = {}
    for signals in cycle_signals(SimConfig(joints=2, cycles=60, seed=7)):
        truth.update({(signals.cycle, j): t["temperature"] for j, t in enumerate(signals.truth)})
        stripped = [replace(j, motor_temperature=np.full_like(j.motor_temperature, np.nan)) for j in signals.joints]
        for symptom in feeder.update(replace(signals, joints=stripped)):
            bank = agent.joints[symptom.joint].detectors
            if bank.temperature is not None:
                assert bank.temperature_source == FRICTION_TEMPERATURE
                seen.append((bank.temperature, truth[(symptom.cycle, symptom.joint)]))
    feeder.finish()
    assert len(seen) >= 2 * 20                     # every cycle after the model (20 cycles of 60)
    assert all(abs(read - true) < 7.5 for read, true in seen), max(abs(r - t) for r, t in seen)
    assert all(not m.temperature_source.motor_seen and m.temperature_source.friction_used for m in agent.joints.values())


def test_a_warm_up_detector_holds_while_the_joint_is_cold_again_after_a_stop() -> None:
    """A joint still in its warm-up stage stops overnight: it restarts at 10 °C, 25 °C below the span its
    warm-up nominals were learned in, where its KL distances sit well above them (seed 401 of the plant week:
    kl_raw 4–6 σ up for ten cycles, which raised a false alarm). The KL and joint-vector detectors hold
    ("below"), the wear evidence decides on. The drop is 25 °C so that the smoothing counts it as a stop at
    once: each reading beyond 3 residual stds (≈ 3·3.2 °C), the pair's mean beyond 4 (12.8 °C), here
    25 ± 2.1 °C (5.7 stds of the pair's mean beyond it). Other side: back inside the span the same shift
    alarms."""
    bank, rng, cycle = _warm_up_bank(4)
    _run(bank, rng, cycle, COLD, 40)                  # 40 more cycles in span: the smoothing trusts its spread
    decisions, raised = _run(bank, rng, cycle + 40, COLD - 25.0, 30, kl_shift=6.0)
    assert not raised and bank.hold_temperature.stops == 1
    for d in decisions:
        assert all(d[q].statistic is None and "below" in d[q].reason and d[q].reason.startswith("held")
                   for q in HELD)
        assert d["wear"].statistic is not None
    _run(bank, rng, cycle + 70, COLD, 10)             # warm again: the smoothing follows within a few cycles
    _, raised = _run(bank, rng, cycle + 80, COLD, 30, kl_shift=6.0)
    assert HELD <= raised


def test_the_spans_and_holds_read_the_smoothed_temperature() -> None:
    """The spans are learned on the smoothed temperature (edge_monitor/pipeline/hold_temperature.py), so
    the scatter's extremes do not widen them: 20 learning cycles at 35 ± 3 °C, the first one at 35 (the
    smoothing starts at its first reading), give a span within 35 ± 4·1.13 °C (the smoothed std is
    3·√(0.25/1.75) = 1.13 °C, and its start at 35 makes it smaller over these cycles; the raw span of 20
    readings would reach ≈ ±5.6 °C). The smoothing state is saved with the detectors and restored."""
    config = DecisionConfig(n_nominal=20, density="gauss", density_joint="gauss", calibration_draws=16,
                            calibration_steps=400, settling_window=1000, arl0_cycles=1000, **HOLD)
    bank = DetectorBank(config, {})
    rng = np.random.default_rng(5)
    cycle = 0
    while bank.collecting:
        bank.observe_temperature(COLD + (rng.normal(0.0, NOISE) if cycle else 0.0))
        bank.update(_inputs(rng), "r", 0, cycle)
        cycle += 1
    expected = NOISE * (0.25 / 1.75) ** 0.5
    for span in bank.spans.learned.values():
        assert COLD - 4 * expected < span.lo <= span.hi < COLD + 4 * expected
    restored = DetectorBank(bank.config, {})
    restored.load_state(json.loads(json.dumps(bank.state_dict(), allow_nan=False)), 0)
    assert restored.hold_temperature.state_dict() == bank.hold_temperature.state_dict()


def test_a_wild_reading_does_not_widen_a_span_and_the_cold_side_holds_without_the_steady_stage() -> None:
    """One reading 40 °C off while a nominal is learned is that cycle's hold temperature but goes into no
    span (spans are min/max: it would widen one for good). With ``steady_relearn = false`` the warm side
    does not hold (nothing would end it) but the cold side does (the joint's warming ends it)."""
    config = DecisionConfig(n_nominal=60, density="gauss", density_joint="gauss", calibration_draws=16,
                            calibration_steps=400, settling_window=1000, arl0_cycles=1000, steady_relearn=False,
                            **HOLD)
    bank = DetectorBank(config, {})
    rng = np.random.default_rng(7)
    for cycle in range(60):           # learning; the smoothing trusts its spread from cycle 33 on
        assert bank.collecting
        bank.observe_temperature(COLD + 40.0 if cycle == 45 else COLD + rng.normal(0.0, NOISE))
        if cycle == 45:
            assert bank.smoothed == COLD + 40.0 and not bank.hold_temperature.confirmed
        bank.update(_inputs(rng), "r", 0, cycle)
    assert not bank.collecting and bank.hold_temperature.jumps == 0
    assert all(s.hi < COLD + 4 * NOISE for s in bank.spans.learned.values()), bank.spans.learned
    decisions, _ = _run(bank, rng, 60, COLD + 25.0, 20, kl_shift=0.0)
    assert not any(d[q].reason.startswith("held") for d in decisions for q in HELD)      # warm side: off
    _run(bank, rng, 80, COLD, 20)
    decisions, raised = _run(bank, rng, 100, COLD - 25.0, 20, kl_shift=6.0)
    assert not raised and all(d[q].reason.startswith("held") for d in decisions for q in HELD)


def test_the_warm_side_holds_beyond_its_margin_and_a_bad_margin_is_a_clear_error() -> None:
    """``decision.warm_up_hold_margin`` (°C): a joint whose smoothed temperature is 4 °C above the span is
    still watched at 6 (the default: a 6 σ KL shift alarms), held at 2; 10 °C above is held at 6.
    Below the span the margin stays max(2 °C, 10 % of the span)."""
    for margin, above, held in ((6.0, 4.0, False), (2.0, 4.0, True), (6.0, 10.0, True)):
        bank, rng, cycle = _warm_up_bank(6, warm_up_hold_margin=margin)
        top = max(bank.spans.learned[q].hi for q in HELD)
        for k in range(20):            # no scatter: the smoothed temperature comes within 0.1 °C of it
            bank.observe_temperature(top + above)
            bank.update(_inputs(rng), "r", 0, cycle + k)
        assert bank.smoothed == pytest.approx(top + above, abs=0.1)
        decisions, raised = [], set()
        for k in range(20, 50):
            bank.observe_temperature(top + above)
            d, alarms = bank.update(_inputs(rng, kl_shift=6.0), "r", 0, cycle + k)
            decisions.append(d)
            raised |= {a.quantity for a in alarms}
        assert all(all(dd[q].reason.startswith("held") == held for q in HELD) for dd in decisions), margin
        assert (HELD & raised == set()) == held, (margin, above, raised)
    for bad in (-1.0, 51.0, "6", True):
        with pytest.raises(ConfigError, match="warm_up_hold_margin"):
            DecisionConfig(warm_up_hold_margin=bad)
