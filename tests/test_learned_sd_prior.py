"""The warm-up nominal's learned sd shrunk towards the input's own by k pseudo-values (``[decision.learned_sd_prior_friction]``,
edge_monitor.stats.densities.with_sd_prior): on a joint without motor temperature the wear score's cold learning window
scatters less than the score does later, and a joint learned that calm alarmed at the default budget
(docs/WITHOUT_MOTOR_TEMPERATURE.md)."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from edge_monitor.config import ConfigError, config_from_mapping
from edge_monitor.pipeline.detectors import DetectorBank
from edge_monitor.pipeline.healthy_drift import LEARNED_SD_PRIOR_FRICTION
from edge_monitor.pipeline.nominal_temperature import FRICTION_TEMPERATURE
from edge_monitor.stats.densities import with_sd_prior
from edge_monitor.stats.detector_config import DetectorConfig, DetectorConfigError
from edge_monitor.stats.sequential_detector import SequentialDetector


def _posterior_sd(s0: float, n: int, k: float, sd: float) -> float:
    return math.sqrt(((n - 1) * s0 ** 2 + k * sd ** 2) / (n - 1 + k))


@settings(max_examples=60, deadline=None)
@given(st.integers(3, 200), st.floats(0.0, 500.0), st.floats(0.05, 20.0), st.floats(0.01, 10.0),
       st.integers(0, 2 ** 32 - 1))
def test_the_widened_values_keep_their_mean_and_correlation_and_take_the_posterior_sd(n, k, prior_sd, scale, seed):
    rng = np.random.default_rng(seed)
    values = rng.normal(size=(n, 2)) @ np.array([[1.0, 0.6], [0.0, 0.8]]) * scale + [3.0, -1.0]
    out = with_sd_prior(values, (k, 0.0), (prior_sd, 1.0))
    s0 = values.std(axis=0, ddof=1)
    np.testing.assert_allclose(out.mean(axis=0), values.mean(axis=0), atol=1e-9 * (1 + scale))
    np.testing.assert_allclose(out.std(axis=0, ddof=1), [_posterior_sd(s0[0], n, k, prior_sd), s0[1]], rtol=1e-9)
    np.testing.assert_allclose(np.corrcoef(out.T)[0, 1], np.corrcoef(values.T)[0, 1], atol=1e-9)
    np.testing.assert_array_equal(with_sd_prior(values, (0.0, 0.0), (1.0, 1.0)), values)


def test_the_shipped_prior_reaches_the_wear_score_of_a_joint_without_motor_temperature_only() -> None:
    """The wear detector and the joint vector's wear axis of such a joint; nothing on a joint with one, nor on the KL
    detectors; ``[]`` takes it away; a bad prior names its key; the steady nominal is fitted as learned."""
    decision = config_from_mapping({}).decision
    k, sd = LEARNED_SD_PRIOR_FRICTION["wear_score"]
    assert decision.detector_config("wear", friction_temperature=True).sd_prior_count == (k,)
    assert decision.detector_config("joint", friction_temperature=True).sd_prior_count == (k, 0.0, 0.0)
    assert decision.detector_config("joint", friction_temperature=True).sd_prior_sd[0] == sd
    for quantity in ("wear", "joint", "kl_raw", "kl_weighted"):
        assert decision.detector_config(quantity).sd_prior_count == ()
    for quantity in ("kl_raw", "kl_weighted"):
        assert decision.detector_config(quantity, friction_temperature=True).sd_prior_count == ()
    none = config_from_mapping({"decision": {"learned_sd_prior_friction": {"wear_score": []}}}).decision
    assert none.detector_config("wear", friction_temperature=True).sd_prior_count == ()
    for bad in ({"wear_score": [-1, 1.0]}, {"wear_score": [20, 0.0]}, {"wear_score": [20]}, {"speed": [20, 1.0]}):
        with pytest.raises(ConfigError, match="decision.learned_sd_prior_friction"):
            config_from_mapping({"decision": {"learned_sd_prior_friction": bad}})
    with pytest.raises(DetectorConfigError, match="sd_prior_count"):
        DetectorConfig(sd_prior_count=(20.0, 1.0), sd_prior_sd=(1.0, 1.0))
    config = DetectorConfig(sd_prior_count=(20.0,), sd_prior_sd=(1.0,))
    calm = np.random.default_rng(1).normal(0.0, 0.4, size=(60, 1))
    np.testing.assert_array_equal(config.learning_values("steady", calm), calm)


def _fed(config: DetectorConfig, learning: np.ndarray, after: np.ndarray) -> tuple[SequentialDetector, int | None]:
    """A detector fed ``learning`` then ``after``; the first cycle it alarms in (None: none)."""
    detector, first = SequentialDetector(config), None
    for cycle, value in enumerate(np.concatenate([learning, after])):
        decision = detector.update(float(value), cycle)
        if decision.alarm and first is None:
            first = cycle
    return detector, first


def test_a_calm_learning_window_is_widened_and_a_wear_step_is_still_found() -> None:
    """Learned from 60 values of sd 0.4, the nominal's sd is the posterior's (0.61), not 0.4; a step of 3 in the
    score's units (≈ 5 of the widened sd) is found within the window's first cycles, as without the prior."""
    rng = np.random.default_rng(7)
    learning = rng.normal(0.0, 0.4, size=60)
    base = DetectorConfig(direction="increase", allowance=0.75, pf=1e-6)
    prior = DetectorConfig(direction="increase", allowance=0.75, pf=1e-6, sd_prior_count=(20.0,), sd_prior_sd=(1.0,))
    step = rng.normal(3.0, 1.0, size=40)
    widened, found = _fed(prior, learning, step)
    plain, found_plain = _fed(base, learning, step)
    assert widened.density is not None and plain.density is not None
    assert widened.density.spread[0] == pytest.approx(_posterior_sd(learning.std(ddof=1), 60, 20.0, 1.0), rel=1e-9)
    assert plain.density.spread[0] == pytest.approx(learning.std(ddof=1), rel=1e-9)
    assert found is not None and found_plain is not None and found - 60 <= 5 and found_plain <= found


def test_a_restart_keeps_the_widened_nominal_and_an_old_state_without_the_prior_relearns() -> None:
    """A joint without motor temperature saves and restores its widened nominal as it is; a state saved before the
    prior existed (its detector fingerprint without it) is relearned with a message naming the detector."""
    decision = config_from_mapping({}).decision
    bank, rng = DetectorBank(decision, {}), np.random.default_rng(3)
    for cycle in range(decision.n_nominal + 2):
        bank.observe_temperature(30.0 + 0.2 * cycle, FRICTION_TEMPERATURE)
        bank.update({"wear_score": float(rng.normal(0.0, 0.4)), "kl_raw": math.exp(rng.normal(-4.0, 0.1)),
                     "kl_weighted": math.exp(rng.normal(-3.5, 0.1))}, "robot", 0, cycle)
    spread = bank.detectors["wear"].density.spread[0]
    saved = json.loads(json.dumps(bank.state_dict()))
    restored = DetectorBank(decision, {})
    assert restored.load_state(saved, 0) == []
    assert restored.detectors["wear"].density.spread[0] == spread
    for quantity in ("wear", "joint"):
        for key in ("sd_prior_count", "sd_prior_sd"):
            del saved[quantity]["config"][key]
    old = DetectorBank(decision, {})
    messages = old.load_state(saved, 0)
    assert len(messages) == 2 and all("relearning" in m for m in messages)
    assert old.detectors["wear"].state == "learning" and old.detectors["kl_raw"].state == "monitoring"
