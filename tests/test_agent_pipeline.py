"""The agent pipeline on protocol frames of synthetic cycles: symptoms, E2E exclusion, cycles
without status frames, and persistence across a restart."""

from __future__ import annotations

import dataclasses
import math
from datetime import datetime, timezone

import numpy as np
import pytest

from edge_monitor.config import AgentConfig, DecisionConfig, KLConfig, ModelConfig, PlateauConfig
from edge_monitor.pipeline.agent import Agent
from edge_monitor.pipeline.state_store import StateStore
from joint_model.friction import friction_magnitude

from synthetic_frames import make_frames

SPEEDS = (8.7, 41.7, 133.5)


def small_config(speeds=SPEEDS, **kw) -> AgentConfig:
    # short synthetic runs: no per-joint model learning (its own tests cover it); detectors learn from 3
    # values, too few for a calibrated threshold (its simulation says so: h ≈ 150 ± 140 nats for 10⁴), so
    # they use the asymptotic one at Pf = 1e-3 (5.4 nats): these tests are about the pipeline, not the
    # calibration (tests/test_gaussian_calibration.py, tests/test_sequential_detector.py)
    return AgentConfig(segmentation=PlateauConfig(speeds=speeds), kl=KLConfig(n_nominal_cycles=2),
                       model=ModelConfig(enabled=False),
                       decision=DecisionConfig(n_nominal=3, density="gauss", pf=1e-3,
                                               quantities=("wear", "kl_raw", "kl_weighted")), **kw)


def feed(agent: Agent, frames, block=1000, start=0, stop=None):
    ids, data, dlc, ts = frames
    stop = len(ids) if stop is None else stop
    outs = []
    for s in range(start, stop, block):
        e = min(s + block, stop)
        outs += agent.update(ids[s:e], data[s:e], dlc[s:e], ts[s:e])
    return outs


@pytest.fixture(scope="module")
def frames():
    return make_frames(4, joints=(0, 1), speeds=SPEEDS, wear=lambda j, c: 20.0 * j, seed=1)


@pytest.fixture(scope="module")
def identifiable_frames():
    """Both joints worn (10 and 20) where the wear likelihood has curvature: on an unworn joint it is flat to
    the rounding of its inputs over ≈ 10⁻⁵ wear units (the wear bump vanishes faster than any power of ϖ), so
    an answer there moves by that much with the summation order of the friction data, beyond the optimiser's
    own tolerance. The tests of how frames are grouped are of the pipeline, not of that flatness."""
    return make_frames(4, joints=(0, 1), speeds=SPEEDS, wear=lambda j, c: 10.0 + 10.0 * j, seed=1)


def test_one_symptom_per_joint_and_cycle_with_model_friction(frames):
    agent = Agent(small_config())
    outs = feed(agent, frames) + agent.finish()
    symptoms = [o.to_dict() for o in outs]
    assert [(s["joint"], s["cycle"]) for s in symptoms] == [(j, c) for c in range(4) for j in (0, 1)]
    stats = agent.run_statistics()
    assert stats["frames_total"] == len(frames[0]) == stats["frames_ok"]
    assert stats["crc_errors"] == stats["counter_lost"] == stats["repeated"] == 0
    for s in symptoms:
        f = s["friction"]
        assert f["speeds"] == list(SPEEDS)
        truth = friction_magnitude(np.array(SPEEDS), 0.5, 40.0, 20.0 * s["joint"])
        # sample noise 2e-3 over ≥ 470 steady samples: stderr ≈ 7e-5; 6 σ plus the torque LSB (5e-5)
        assert np.all(np.abs(np.array(f["torque"]) - truth) < 6 * np.array(f["stderr"]) + 5e-5)
        assert set(s["decisions"]) == {"wear", "kl_raw", "kl_weighted"}
        assert s["schema"] == 1 and s["robot"] == "robot1"
    # Load estimate error (σl = 0.1) dominates the wear estimate; the CRLB std includes it.
    for s in symptoms[-2:]:
        w = s["wear"]
        assert w["std"] > 0
        assert abs(w["estimate"] - 20.0 * s["joint"]) < 4 * w["std"] + 1.0
    assert symptoms[-1]["decisions"]["wear"]["state"] == "monitoring"


def test_corrupted_frames_are_counted_and_excluded(frames):
    ids, data, dlc, ts = (a.copy() for a in frames)
    rng = np.random.default_rng(7)
    hit = rng.choice(len(ids), size=200, replace=False)
    data[hit, rng.integers(0, 8, hit.size)] ^= np.uint8(1 << 3)
    agent = Agent(small_config())
    outs = feed(agent, (ids, data, dlc, ts)) + agent.finish()
    stats = agent.run_statistics()
    assert stats["crc_errors"] == 200
    assert stats["frames_ok"] <= stats["frames_total"] - 200
    clean = Agent(small_config())
    ref = feed(clean, frames) + clean.finish()
    for a, b in zip(outs, ref):
        np.testing.assert_allclose(a.to_dict()["friction"]["torque"], b.to_dict()["friction"]["torque"], atol=2e-4)


def test_cycles_inferred_without_status_frames():
    frames = make_frames(3, joints=(0,), speeds=SPEEDS, status=False, seed=2)
    agent = Agent(small_config())
    outs = feed(agent, frames) + agent.finish()
    assert [o.to_dict()["cycle"] for o in outs] == [0, 1, 2]
    assert all(o.to_dict()["friction"]["speeds"] == list(SPEEDS) for o in outs)


def test_restart_resumes_without_duplicates_or_gaps(frames, tmp_path):
    ids = frames[0]
    split = len(ids) // 2 + 123
    cfg = small_config()
    first = Agent(cfg, state_store=StateStore(tmp_path))
    outs1 = feed(first, frames, stop=split)
    first.close()
    second = Agent(cfg, state_store=StateStore(tmp_path))
    outs2 = feed(second, frames, start=split) + second.finish()
    keys = [(o.to_dict()["joint"], o.to_dict()["cycle"]) for o in outs1 + outs2]
    assert sorted(keys) == [(j, c) for j in (0, 1) for c in range(4)]
    assert len(set(keys)) == len(keys)
    # the restored detectors carry on: no re-learning from scratch
    assert outs2[-1].to_dict()["decisions"]["wear"]["state"] == "monitoring"
    # the first cycle after the restart began before it: published, marked partial, kept from the detectors
    first_after = [o.to_dict() for o in outs2 if o.to_dict()["joint"] == 0][0]
    assert first_after.get("partial") is True
    assert first_after["decisions"]["wear"]["reason"].startswith("partial cycle")
    # the controller's cycle counter starting again at 0 (a controller restart) continues the numbering
    second.close()
    third = Agent(cfg, state_store=StateStore(tmp_path))
    outs3 = feed(third, frames) + third.finish()
    assert sorted({o.to_dict()["cycle"] for o in outs3}) == [4, 5, 6, 7]
    assert not any(o.to_dict().get("partial") for o in outs3)


@pytest.mark.parametrize("on_change", ["relearn", "keep"])
def test_a_config_change_after_a_restart_takes_effect_or_is_kept_and_is_reported(tmp_path, caplog, on_change):
    frames = make_frames(8, joints=(0, 1), speeds=SPEEDS, wear=lambda j, c: 0.0, seed=3)
    split = len(frames[0]) * 6 // 8 + 123
    first = Agent(small_config(), state_store=StateStore(tmp_path))
    feed(first, frames, stop=split)
    first.close()
    assert first.joints[0].detectors.detectors["wear"].state == "monitoring"
    changed = small_config(on_config_change=on_change)
    changed = dataclasses.replace(changed, decision=dataclasses.replace(changed.decision, allowance=0.5))
    with caplog.at_level("WARNING"):
        second = Agent(changed, state_store=StateStore(tmp_path))
        outs = feed(second, frames, start=split)
    detector = second.joints[0].detectors.detectors["wear"]
    if on_change == "relearn":   # the new allowance takes effect: the detector learns again, and says why
        assert detector.config.allowance == 0.5 and outs[0].decisions["wear"].state == "learning"
        assert any("allowance 0.75 → 0.5" in r.getMessage() and "relearning" in r.getMessage()
                   for r in caplog.records)
    else:                        # the learned detector is kept, with the allowance it was learned with; reported
        assert detector.config.allowance == 0.75 and outs[-1].decisions["wear"].state == "monitoring"
        assert any("keeping the models learned with the previous decision" in r.getMessage() for r in caplog.records)
        second.declare_maintenance(0)       # a maintenance declaration adopts the current config
        assert second.joints[0].detectors.detectors["wear"].config.allowance == 0.5


def _restarted_with(tmp_path, caplog, on_change: str, **decision_changes):
    """A calibrated agent stopped at a split, restarted with ``decision_changes`` and fed the rest: the wear
    detector before and after, after checking that nothing was relearned or kept under old settings."""
    frames = make_frames(8, joints=(0, 1), speeds=SPEEDS, wear=lambda j, c: 0.0, seed=3)
    split = len(frames[0]) * 6 // 8 + 123
    calibrated = small_config(on_config_change=on_change)
    calibrated = dataclasses.replace(calibrated, decision=dataclasses.replace(calibrated.decision, pf=None,
                                                                             arl0_cycles=1e4))
    first = Agent(calibrated, state_store=StateStore(tmp_path))
    feed(first, frames, stop=split)
    first.close()
    before = first.joints[0].detectors.detectors["wear"]
    assert before.state == "monitoring" and before.threshold is not None and before.calibration is not None
    changed = dataclasses.replace(calibrated, decision=dataclasses.replace(calibrated.decision, **decision_changes))
    with caplog.at_level("WARNING"):
        second = Agent(changed, state_store=StateStore(tmp_path))
        outs = feed(second, frames, start=split) + second.finish()
    assert outs[-1].decisions["wear"].state == "monitoring"              # not relearned
    assert not any("relearning" in r.getMessage() or "keeping the models" in r.getMessage() for r in caplog.records)
    return before, second.joints[0].detectors.detectors["wear"]


@pytest.mark.parametrize("on_change", ["relearn", "keep"])
def test_a_new_false_alarm_target_after_a_restart_rederives_the_thresholds_without_relearning(tmp_path, caplog,
                                                                                              on_change):
    """The ARL0 target is not what a detector learned: a restart with another budget keeps the nominals
    and re-derives every threshold for the new target (tests/test_false_alarm_budget.py has the maths)."""
    before, after = _restarted_with(tmp_path, caplog, on_change, arl0_cycles=500.0)
    assert after.arl0 == 500.0 and after.calibration is not None and after.calibration.arl0 == 500.0
    assert after.threshold is not None and after.threshold < before.threshold    # a shorter run length


@pytest.mark.parametrize("on_change", ["relearn", "keep"])
def test_new_calibration_settings_after_a_restart_rederive_the_thresholds_without_relearning(tmp_path, caplog,
                                                                                             on_change):
    """Where the calibration simulates (the allowance boundary, a measured drift) is not learned either: an
    upgrade that changes it keeps every nominal and re-derives the thresholds, under "keep" too."""
    before, after = _restarted_with(tmp_path, caplog, on_change, calibrate_at="boundary")
    assert before.calibration.at == "healthy_drift"
    assert after.calibration is not None and after.calibration.at == "boundary"
    assert after.threshold is not None and after.threshold != before.threshold


def test_config_errors_name_the_field():
    from edge_monitor.config import ConfigError, config_from_mapping
    with pytest.raises(ConfigError, match=r"decision\.pf"):
        config_from_mapping({"decision": {"pf": 2.0}})
    with pytest.raises(ConfigError, match=r"friction\.fc0"):
        config_from_mapping({"friction": {"fc0": "abc"}})
    with pytest.raises(ConfigError, match=r"wear\.bogus"):
        config_from_mapping({"wear": {"bogus": 1}})
    with pytest.raises(ConfigError, match=r"decision\.n_nominal.*joint"):
        config_from_mapping({"decision": {"n_nominal": 3, "density": "gauss"}})
    cfg = config_from_mapping({"robot": "r7", "segmentation": {"speeds": [5.0, 50.0]}})
    assert cfg.robot == "r7" and cfg.segmentation.speeds == (5.0, 50.0)
    assert dataclasses.replace(cfg).decision.pf == cfg.decision.pf


def test_shipped_example_config_equals_embedded_defaults():
    from pathlib import Path

    import edge_monitor
    from edge_monitor.config import load_config
    example = Path(edge_monitor.__file__).parent / "defaults" / "agent.toml"
    assert load_config(example) == AgentConfig()


def test_alarm_is_raised_once_and_cleared_by_a_declared_maintenance():
    # 5 healthy cycles (3 learn the nominal model), then the gearbox is badly worn; winsorised at 3σ a
    # jump counts like a 3σ shift per cycle, so it takes a few cycles (docs/DETECTION.md)
    frames = make_frames(14, joints=(0,), speeds=SPEEDS, wear=lambda j, c: 0.0 if c < 5 else 60.0, seed=9)
    sink_alarms = []

    class Sink:
        def on_symptom(self, output): pass
        def on_alarm(self, alarm): sink_alarms.append(alarm)
        def on_health(self, health): pass
        def close(self): pass

    agent = Agent(small_config(), sinks=[Sink()])
    outs = feed(agent, frames)
    raised = [a.to_dict() for a in sink_alarms if a.state == "raised"]
    assert raised and {a["quantity"] for a in raised} >= {"wear"}
    assert len(raised) == len({a["quantity"] for a in raised})            # each quantity raised once
    assert all(a["cycle"] >= 5 for a in raised)                            # never before the wear
    assert outs[-1].to_dict()["alarm"] is True
    cleared = [a.to_dict() for a in agent.declare_maintenance(0)]
    assert {a["quantity"] for a in cleared} == {a["quantity"] for a in raised}
    assert all(a["state"] == "cleared" for a in cleared)
    assert agent.joints[0].maintenances == 1
    after = agent.finish()
    assert after[-1].to_dict()["decisions"]["wear"]["state"] == "learning"
    assert after[-1].to_dict()["alarm"] is False


def test_a_restart_in_a_later_cycle_marks_the_cycle_it_joined_partial(frames, tmp_path):
    """Killed early in one cycle, restarted in the middle of a later one: the cycle joined mid-way is
    published partial (it feeds neither learning nor the detectors); the next one is whole."""
    ids, data = frames[0], frames[1]
    status = np.flatnonzero(ids == 0x080)
    cycle = (data[status].view("<u8").reshape(-1) >> np.uint64(16)) & np.uint64(0xFFFF)
    first_row = {int(c): int(status[np.argmax(cycle == c)]) for c in np.unique(cycle)}
    first = Agent(small_config(), state_store=StateStore(tmp_path))
    feed(first, frames, stop=first_row[1] + 50)
    first.save_state()                                   # then killed: no close
    second = Agent(small_config(), state_store=StateStore(tmp_path))
    resume = (first_row[2] + first_row[3]) // 2
    outs = [o.to_dict() for o in feed(second, frames, start=resume) + second.finish()]
    by_cycle = {(o["joint"], o["cycle"]): o for o in outs}
    assert by_cycle[(0, 2)].get("partial") is True and by_cycle[(1, 2)].get("partial") is True
    assert not by_cycle[(0, 3)].get("partial")


def test_a_cycle_cut_by_a_controller_restart_is_published_partial(frames):
    """The controller restarts in the middle of cycle 2 (its counters start again at 0): cycle 2 ended
    early, so it is published partial (kept from learning and the detectors); numbering goes on."""
    ids, data = frames[0], frames[1]
    status = np.flatnonzero(ids == 0x080)
    cycle = (data[status].view("<u8").reshape(-1) >> np.uint64(16)) & np.uint64(0xFFFF)
    first_row = {int(c): int(status[np.argmax(cycle == c)]) for c in np.unique(cycle)}
    cut = (first_row[2] + first_row[3]) // 2
    agent = Agent(small_config())
    outs = feed(agent, frames, stop=cut) + feed(agent, frames, stop=first_row[2] + 50) + agent.finish()
    by_cycle = {(o.joint, o.cycle): o.to_dict() for o in outs}
    assert sorted({c for _, c in by_cycle}) == [0, 1, 2, 3, 4, 5]
    # cycle 5 is cut by the end of the stream (50 frames into it): partial as well
    assert [bool(by_cycle[(0, c)].get("partial")) for c in range(6)] == [False, False, True, False, False, True]


def test_the_last_cycle_is_partial_when_the_stream_stops_inside_it(frames):
    """End of a log or `run --idle-stop` in the middle of a cycle: the cycle's last segment was not
    reached (segments of the previous whole cycle tell how far a cycle goes), so it is partial; a
    stream that ends after a whole cycle publishes it whole."""
    ids, data = frames[0], frames[1]
    status = np.flatnonzero(ids == 0x080)
    cycle = (data[status].view("<u8").reshape(-1) >> np.uint64(16)) & np.uint64(0xFFFF)
    first_row = {int(c): int(status[np.argmax(cycle == c)]) for c in np.unique(cycle)}
    cut = Agent(small_config())
    outs = feed(cut, frames, stop=(first_row[2] + first_row[3]) // 2) + cut.finish()
    assert [bool(o.to_dict().get("partial")) for o in outs if o.joint == 0] == [False, False, True]
    whole = Agent(small_config())
    outs = feed(whole, frames) + whole.finish()
    assert not any(o.to_dict().get("partial") for o in outs)


def test_a_controller_restart_is_seen_by_its_tick_even_when_the_cycle_number_looks_like_progress():
    """Restart near the counter's wrap (64600 → 0 is 936 steps 'forward') or into the same cycle number:
    the controller tick going backward tells, once the next status frames continue the new tick."""
    from edge_monitor.sources.cycle_numbering import CONFIRMATIONS, CycleNumbering

    for before, after in ((64_600, 0), (5, 5)):
        numbering = CycleNumbering()
        assert numbering.update(before, 3, 900_000, {}) == before
        pending = [numbering.update(after, 0, 10 + 10 * k, {}) for k in range(CONFIRMATIONS)]
        assert pending == [None] * CONFIRMATIONS                  # not yet confirmed
        assert numbering.update(after, 0, 10 + 10 * CONFIRMATIONS, {}) == before + 1   # numbering goes on
        assert numbering.restarted and numbering.taken_back == CONFIRMATIONS and numbering.restarts == 1
    numbering = CycleNumbering()                      # ordinary progress: no restart
    numbering.update(7, 5, 1000, {})
    assert numbering.update(8, 0, 1010, {}) == 8 and not numbering.restarted and numbering.jumps == 0


def _numbers_close(a, b, rel: float = 1e-7, atol: float = 1e-12, spread=None) -> bool:
    """Equal records, floats to within ``rel`` or, near zero, ``atol``; a list of floats (a density grid)
    to within ``rel`` of its largest element: the summation order differs with the block size, and a
    grid's small masses carry the rounding of its large ones (measured with numpy 2.4: 2·10⁻⁷ relative
    on a mass of 10⁻⁴ after a 10⁻¹³ change of the temperature the samples were compensated to). ``spread`` (a record of the same shape, or None) adds to each
    float's tolerance how far that number moves when the wear optimiser's answer moves within its own
    convergence tolerance (see ``_optimiser_slack``)."""
    if isinstance(a, dict) and isinstance(b, dict):
        return a.keys() == b.keys() and all(
            _numbers_close(a[k], b[k], rel, atol, spread.get(k) if isinstance(spread, dict) else None) for k in a)
    if isinstance(a, list) and isinstance(b, list):
        spreads = spread if isinstance(spread, list) and len(spread) == len(a) else [None] * len(a)
        if a and all(isinstance(x, float) for x in a):     # a vector (a density grid): norm-wise, since a
            atol = max(atol, rel * max(abs(x) for x in a))  # sum's rounding scales with its largest terms
        return len(a) == len(b) and all(_numbers_close(x, y, rel, atol, s) for x, y, s in zip(a, b, spreads))
    if isinstance(a, float) and isinstance(b, float):
        slack = spread if isinstance(spread, float) else 0.0
        return a == b or abs(a - b) <= rel * max(abs(a), abs(b)) + atol + slack
    return a == b


def _add_difference(total, a, b):
    """``total`` (a record of the same shape, floats or None) plus |a − b| field by field."""
    if isinstance(a, dict) and isinstance(b, dict):
        total = total if isinstance(total, dict) else {}
        return {k: _add_difference(total.get(k), a[k], b.get(k)) for k in a}
    if isinstance(a, list) and isinstance(b, list) and len(a) == len(b):
        total = total if isinstance(total, list) and len(total) == len(a) else [None] * len(a)
        return [_add_difference(t, x, y) for t, x, y in zip(total, a, b)]
    if isinstance(a, float) and isinstance(b, float):
        return (total if isinstance(total, float) else 0.0) + abs(a - b)
    return total


def _nudged_wear_optimiser(monkeypatch, which: int, calls: list[float]):
    """Replace the wear estimator's bounded Brent search by one whose ``which``-th answer (counted
    from 0 in ``calls``) is moved by the distance scipy promises it to be within of the optimum,
    |x − x*| ≤ 2·(√ε·|x| + xatol/3) with the xatol the estimator itself passes: what a CPU with
    other rounding may return."""
    import edge_monitor.features.wear_estimation as wear_estimation

    brent = wear_estimation.minimize_scalar

    def nudged(*args, **kwargs):
        fit = brent(*args, **kwargs)
        xatol = kwargs.get("options", {}).get("xatol", 1e-5)        # scipy's default when none is given
        bound = 2.0 * (math.sqrt(np.finfo(float).eps) * abs(float(fit.x)) + xatol / 3.0)
        if len(calls) == which:
            fit.x = float(fit.x) + bound
        calls.append(bound)
        return fit

    monkeypatch.setattr(wear_estimation, "minimize_scalar", nudged)


_SAMPLE_LEVEL: dict[tuple, list[dict]] = {}     # the reference runs, once per segmentation mode
_SLACK: dict[tuple, list[dict]] = {}            # how far they may move within the optimiser's tolerance


def _optimiser_slack(symptoms, monkeypatch) -> list[dict]:
    """First-order bound, field by field, on how far the records move when every wear optimiser
    answer moves anywhere within its tolerance: Σᵢ |record(answer i nudged) − record|, doubled (the
    reference and the run compared with it may each land anywhere)."""
    base, slack, which, n_calls = symptoms(2500, 512), None, 0, 1
    while which < n_calls:
        calls: list[float] = []
        with monkeypatch.context() as nudging:
            _nudged_wear_optimiser(nudging, which, calls)
            nudged = symptoms(2500, 512)
        n_calls, which = len(calls), which + 1
        assert n_calls, "the wear estimator no longer calls minimize_scalar: derive the tolerance anew"
        slack = [_add_difference(s, a, b) for s, a, b in zip(slack or [None] * len(base), base, nudged)]
    return [_scaled(s, 2.0) for s in slack or []]


def _scaled(record, factor: float):
    """``record`` with every float multiplied by ``factor``."""
    if isinstance(record, dict):
        return {k: _scaled(v, factor) for k, v in record.items()}
    if isinstance(record, list):
        return [_scaled(v, factor) for v in record]
    return record * factor if isinstance(record, float) else record


@pytest.mark.parametrize("speeds", [SPEEDS, ()], ids=["configured speeds", "levels from segment codes"])
@pytest.mark.parametrize("block", [7, 90, 2500, 100_000])
def test_symptoms_do_not_depend_on_how_frames_are_grouped_into_blocks(identifiable_frames, block, speeds, monkeypatch):
    """Live, a block is whatever arrived in ``LiveSource.batch_s``; a joint gathers samples into
    batches before its sample-level work (joint_monitor.SAMPLE_BATCH). The symptoms, learning and
    monitoring cycles alike, equal those of a sample-level pass over blocks of 7 frames without that
    gathering, in both segmentation modes (the shipped default is levels from segment codes).

    "Equal" is to rounding, plus what the wear estimator promises: its bounded Brent search stops
    within a tolerance, and another summation order (another block size, another CPU's SIMD) may land
    anywhere inside it (0.35 µ-wear on one Xeon: 3e-7 relative). So each number may also differ by
    its first-order movement when the optimiser's answers move within that tolerance (the wear
    estimate, the temperature at it and the KL quantities compensated with that temperature move;
    the friction curve and the rest do not)."""
    import edge_monitor.pipeline.joint_monitor as joint_monitor

    def symptoms(size, batch):
        monkeypatch.setattr(joint_monitor, "SAMPLE_BATCH", batch)
        agent = Agent(small_config(speeds))
        return [s.to_dict() for s in feed(agent, identifiable_frames, block=size) + agent.finish()]

    if speeds not in _SAMPLE_LEVEL:
        _SAMPLE_LEVEL[speeds] = symptoms(7, 1)
        _SLACK[speeds] = _optimiser_slack(symptoms, monkeypatch)
    reference, grouped = _SAMPLE_LEVEL[speeds], symptoms(block, 512)
    assert len(reference) == len(grouped) == len(_SLACK[speeds]) == 8
    assert {s["decisions"]["wear"]["state"] for s in reference} == {"learning", "monitoring"}
    for a, b, slack in zip(reference, grouped, _SLACK[speeds]):
        assert _numbers_close(a, b, spread=slack), (a["joint"], a["cycle"])
    # The slack is the optimiser's, not a blanket: the wear estimate gets ≈ 4·xatol/3, the friction none.
    assert 0 < max(s["wear"]["estimate"] for s in _SLACK[speeds]) < 1e-5
    assert all(s["friction"]["torque"] == [0.0] * len(s["friction"]["torque"]) for s in _SLACK[speeds])


def test_a_stream_that_stops_inside_a_cycle_keeps_its_gathered_samples(frames, monkeypatch):
    """``finish(close_open_cycle=False)`` (a replay with --no-close, a run stopped by a signal): the
    joints' saved state (counters, the open cycle's KL window) covers every sample received, as
    without the gathering. Floats to 10⁻⁵: the wear optimiser stops within 10⁻⁶ (xatol), and where its
    likelihood is flat (an unworn joint) another summation order of the same samples moves its answer, and
    what is compensated with it, by up to ≈ 10⁻⁶ (measured 2·10⁻⁷); a sample lost or counted twice moves
    a KDE mass by ≈ 1/N ≥ 10⁻⁴ and a counter by 1."""
    import edge_monitor.pipeline.joint_monitor as joint_monitor

    def states(batch):
        monkeypatch.setattr(joint_monitor, "SAMPLE_BATCH", batch)
        agent = Agent(small_config(()))
        feed(agent, frames, block=90, stop=len(frames[0]) * 5 // 8)
        agent.finish(close_open_cycle=False)
        return {j: m.state_dict() for j, m in agent.joints.items()}

    gathered, unbatched = states(512), states(1)
    assert gathered.keys() == unbatched.keys() == {0, 1}
    for joint in gathered:
        assert _numbers_close(gathered[joint], unbatched[joint], atol=1e-5), joint


def test_records_carry_utc_wall_time_from_the_frame_timestamps_across_a_tick_wrap():
    """The controller's 24-bit tick wraps (every ≈ 9.3 h at 500 Hz) in the second cycle: the controller
    time ``t`` goes on, and each record's ``utc`` is the timestamp of its cycle's last frame."""
    start_time = 1_795_000_000.0                      # 2026-11-18T09:46:40Z
    start_tick = (1 << 24) - 6000                     # the wrap falls into cycle 1 (cycles are 4850 ticks)
    frames = make_frames(4, joints=(0,), speeds=SPEEDS, seed=3, start_tick=start_tick, start_time=start_time)
    agent = Agent(small_config())
    symptoms = [s.to_dict() for s in feed(agent, frames) + agent.finish()]
    ids, ts = frames[0], frames[3]
    status_rows = np.flatnonzero(ids == 0x080)
    cycle_len = len(ids) // 4
    assert [s["cycle"] for s in symptoms] == [0, 1, 2, 3]
    assert symptoms[0]["t"] > (1 << 24) / 500 - 12                                 # the controller's own clock
    assert np.diff([s["t"] for s in symptoms]) == pytest.approx([4850 / 500] * 3, abs=0.01)  # no jump at the wrap
    for s in symptoms:
        last_frame = ts[min((s["cycle"] + 1) * cycle_len, len(ts)) - 1]
        expected = datetime.fromtimestamp(last_frame, tz=timezone.utc)
        assert s["utc"].endswith("Z")
        assert abs((datetime.fromisoformat(s["utc"].replace("Z", "+00:00")) - expected).total_seconds()) < 1e-3
    assert status_rows.size and symptoms[-1]["utc"] > symptoms[0]["utc"]


def test_records_without_wall_clock_timestamps_say_so_with_a_null_utc(frames):
    """A log with relative time (ASC, a simulated clock at 0): the controller time only."""
    agent = Agent(small_config())
    symptoms = [s.to_dict() for s in feed(agent, frames) + agent.finish()]
    assert symptoms and all(s["utc"] is None and s["t"] > 0 for s in symptoms)


@pytest.mark.parametrize("hours", [0.0, 60.0])
def test_the_agent_measures_its_cycle_rate_and_rederives_the_thresholds(hours):
    """Both sides: frames over seconds never show a day, the thresholds stay for the configured 300
    cycles a day; the same frames stretched over 60 hours show a few cycles a day, far outside ±25 %,
    and every learned detector re-derives its threshold for the measured rate (health says so)."""
    ids, data, dlc, ts = make_frames(10, joints=(0,), speeds=SPEEDS, wear=lambda j, c: 0.0, seed=5)
    if hours:
        ts = ts[0] + (ts - ts[0]) * (hours * 3600.0 / float(ts[-1] - ts[0]))
    config = small_config()
    config = dataclasses.replace(config, decision=dataclasses.replace(config.decision, pf=None))
    agent = Agent(config)
    feed(agent, (ids, data, dlc, ts))
    agent.finish()
    health = agent.health().counters
    detector = agent.joints[0].detectors.detectors["wear"]
    assert detector.state == "monitoring" and detector.calibration is not None
    if not hours:
        assert health["cycles_per_day_measured"] is None and health["threshold_rederivations"] == 0
        assert detector.calibration.arl0 == config.decision.arl0_for(300.0, 1)     # one joint seen: all of it
    else:
        measured = health["cycles_per_day_measured"]
        assert measured is not None and abs(measured / 300.0 - 1.0) > 0.25
        basis = health["cycles_per_day"]                  # the rate re-derived for: within ±25 % of now
        assert health["threshold_rederivations"] >= 1 and abs(measured / basis - 1.0) <= 0.25
        assert detector.calibration.arl0 == pytest.approx(config.decision.arl0_for(basis, 1))
        assert health["arl0_cycles"] == pytest.approx(config.decision.arl0_for(basis, 1))


@pytest.mark.parametrize("stated", [None, 6])
def test_a_native_robot_splits_its_budget_over_the_joints_it_sends(stated):
    """Both sides: a 2-joint robot on our frames that states no joint count gets half of the budget per joint
    (its detectors calibrated for a third of a 6-joint share's run length), and a third joint appearing after
    every threshold was learned re-derives them all; stated, the split stays."""
    from protocol.frames import JOINT_STATUS_BASE_ID, MOTOR_STATE_BASE_ID
    ids, data, dlc, ts = make_frames(12, joints=(0, 1, 2), speeds=SPEEDS, wear=lambda j, c: 0.0, seed=7)
    late = (ids == MOTOR_STATE_BASE_ID + 2) | (ids == JOINT_STATUS_BASE_ID + 2)
    keep = ~late | (np.arange(ids.size) >= ids.size // 2)          # joint 2 on the bus from the middle on
    config = small_config()
    config = dataclasses.replace(config, decision=dataclasses.replace(config.decision, pf=None,
                                                                      joints_per_robot=stated))
    agent = Agent(config)
    half = int(np.searchsorted(np.flatnonzero(keep), ids.size // 2))
    frames = (ids[keep], data[keep], dlc[keep], ts[keep])
    feed(agent, frames, stop=half)
    first = agent.joints[0].detectors.detectors["wear"].calibration
    assert first is not None and sorted(agent.joints) == [0, 1]
    feed(agent, frames, start=half)
    agent.finish()
    health = agent.health().counters
    detector = agent.joints[0].detectors.detectors["wear"]
    if stated is None:
        assert first.arl0 == pytest.approx(config.decision.arl0 * 2 / 6)
        assert health["budget_joints"] == 3 and detector.calibration.arl0 == pytest.approx(config.decision.arl0 / 2)
    else:
        assert health["budget_joints"] == 6
        assert first.arl0 == detector.calibration.arl0 == config.decision.arl0


def test_a_cycle_whose_close_fails_is_not_closed_again_on_every_later_block(frames, monkeypatch):
    """An unexpected error while a cycle is closed (the live loop counts it in processing_errors) must not leave
    that cycle open: every later block would try to close it again, fail again, and publish nothing until a
    restart (found by an attack pass). The later cycles are published as without the error."""
    from edge_monitor.pipeline.joint_monitor import JointMonitor

    clean = Agent(small_config())
    expected = sorted((s.joint, s.cycle) for s in feed(clean, frames) + clean.finish())
    failing_cycle = expected[0][1]
    real_end_cycle = JointMonitor.end_cycle

    def end_cycle(self, cycle, *args, **kwargs):
        if cycle == failing_cycle:
            raise RuntimeError("a bug while closing the cycle")
        return real_end_cycle(self, cycle, *args, **kwargs)

    monkeypatch.setattr(JointMonitor, "end_cycle", end_cycle)
    agent, outs, errors = Agent(small_config()), [], 0
    ids, data, dlc, ts = frames
    for s in range(0, len(ids), 1000):          # as the live loop does: a block that raises is counted, not fatal
        try:
            outs += agent.update(ids[s:s + 1000], data[s:s + 1000], dlc[s:s + 1000], ts[s:s + 1000])
        except RuntimeError:
            errors += 1
    outs += agent.finish()
    published = sorted((s.joint, s.cycle) for s in outs)
    assert errors == 1
    later = [key for key in expected if key[1] > failing_cycle + 1]    # the next cycle lost part of its block
    assert later and set(later) <= set(published)
    assert not any(cycle == failing_cycle for _, cycle in published)
