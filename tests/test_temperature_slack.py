"""The temperature slack (``[decision.temperature_slack]``): while the joint's temperature is outside the span a
detector's nominal was learned in, the detector keeps testing, its value less c·√d nominal standard deviations
(d the distance in °C), instead of holding. Both sides: a healthy drift within the slack stays quiet, a wear
shift beyond it alarms, and without the slack the same healthy drift alarms (docs/DETECTION.md, "Watching
while the joint warms")."""

from __future__ import annotations

import json
import math
from types import SimpleNamespace

import numpy as np
import pytest

from edge_monitor.errors import ConfigError
from edge_monitor.pipeline.detectors import DecisionConfig, DetectorBank
from edge_monitor.pipeline.nominal_temperature import NominalSpans
from edge_monitor.pipeline.operating_range import Span

#: Where the warm-up nominals are learned, and the cycle-mean motor temperature's scatter [°C].
COLD, NOISE = 35.0, 3.0
#: How far the joint warms beyond that (the simulator's joints warm ≈ 25 °C).
WARMING = 25.0
SLACK = {"wear_score": 0.0, "kl_raw": 0.21, "kl_weighted": 0.27}
KL = ("kl_raw", "kl_weighted", "joint")
#: Target run length: over the 150 monitored cycles of a test, 4 detectors expect 4·150/1e5 = 0.006 false alarms.
ARL0 = 1e5


def _inputs(rng: np.random.Generator, shift: dict[str, float]) -> dict[str, float]:
    """One cycle: the wear score N(0, 1), the logs of the KL distances N(−3, 0.3), N(−4, 0.3), each moved by
    ``shift`` of its σ."""
    return {"wear_score": rng.normal(shift.get("wear_score", 0.0), 1.0),
            "kl_raw": float(np.exp(rng.normal(-3.0 + 0.3 * shift.get("kl_raw", 0.0), 0.3))),
            "kl_weighted": float(np.exp(rng.normal(-4.0 + 0.3 * shift.get("kl_weighted", 0.0), 0.3)))}


def _bank(seed: int, **settings) -> tuple[DetectorBank, np.random.Generator, int]:
    """Warm-up nominals learned at 35 ± 3 °C (60 values), monitoring; the settling window keeps the stage."""
    config = DecisionConfig(density="gauss", density_joint="gauss", settling_window=1000, arl0_cycles=ARL0,
                            **settings)
    bank = DetectorBank(config, {})
    rng = np.random.default_rng(seed)
    cycle = 0
    while bank.collecting:
        bank.observe_temperature(COLD + rng.normal(0.0, NOISE))
        bank.update(_inputs(rng, {}), "r", 0, cycle)
        cycle += 1
    return bank, rng, cycle


def _warm_run(bank: DetectorBank, rng: np.random.Generator, cycle: int, drift: float, cycles: int = 150,
              wear: float = 0.0) -> tuple[set[str], list[dict]]:
    """The joint warms to COLD + WARMING over the first 50 cycles; its KL inputs drift ``drift``·√(d/WARMING) σ
    (a healthy joint's drift grows like the root of the distance, d the smoothed excess over the span),
    ``wear`` σ more on every input once warm."""
    top = max(bank.spans.learned[q].hi for q in KL)
    raised, decisions = set(), []
    for k in range(cycles):
        temperature = COLD + WARMING * min(1.0, k / 50)
        bank.observe_temperature(temperature + rng.normal(0.0, NOISE))
        d = max(0.0, temperature - top)
        kl = drift * math.sqrt(d / WARMING) + (wear if k >= 50 else 0.0)
        decided, alarms = bank.update(_inputs(rng, {"kl_raw": kl, "kl_weighted": kl,
                                                     "wear_score": wear if k >= 50 else 0.0}), "r", 0, cycle + k)
        decisions.append(decided)
        raised |= {a.quantity for a in alarms}
    return raised, decisions


def test_a_healthy_warming_joint_is_watched_every_cycle_and_stays_quiet() -> None:
    """The KL inputs drift 1.2 σ by the time the joint is 25 °C warmer (the largest measured healthy drift at
    17 °C was 1.5 σ; at the 23 °C or so above the span the slack is 0.21·√23 = 1.0 σ and 0.27·√23 = 1.3 σ, so
    the tested value sits within 0.2 σ of the nominal, well inside the 0.75 σ allowance): no alarm, and every
    detector tests every cycle (no hold)."""
    bank, rng, cycle = _bank(1, temperature_slack=SLACK)
    raised, decisions = _warm_run(bank, rng, cycle, drift=1.2)
    assert raised == set()
    assert all(d[q].statistic is not None and not d[q].reason.startswith("held") for d in decisions for q in d)
    assert set(bank.reasons.values()) == {"tested"}


def test_without_the_slack_the_same_healthy_drift_alarms() -> None:
    """The other side: 2.5 σ of drift (a joint twice as far out as the largest measured) with no slack is a
    shift of 1.75 σ beyond the allowance: ≈ 1.5 nats a cycle, so the KL detectors cross their thresholds
    within the 100 warm cycles. With the slack (1.0–1.3 σ at 23 °C) the same values are tested 1.2–1.5 σ up,
    0.45–0.75 σ beyond the allowance; they are allowed to alarm there too — the slack covers measured healthy
    joints, not twice the largest."""
    bank, rng, cycle = _bank(2, temperature_slack=dict.fromkeys(SLACK, 0.0))
    raised, _ = _warm_run(bank, rng, cycle, drift=2.5)
    assert {"kl_raw", "kl_weighted"} <= raised


def test_wear_beyond_the_slack_alarms_on_a_warm_joint() -> None:
    """A 4 σ shift on every input once the joint is warm (critical wear moves the log KL distances 4–5 σ on the
    simulated joints) on top of the healthy 1.2 σ drift: every detector alarms."""
    bank, rng, cycle = _bank(3, temperature_slack=SLACK)
    raised, _ = _warm_run(bank, rng, cycle, drift=1.2, wear=4.0)
    assert {"wear", "kl_raw", "kl_weighted", "joint"} <= raised


def test_the_slack_grows_with_the_root_of_the_distance_on_either_side() -> None:
    spans = NominalSpans({"joint": Span(40.0, 45.0), "kl_raw": Span(40.0, 45.0)}, slack=SLACK)
    monitoring = SimpleNamespace(state="monitoring", stage="warm-up")
    inputs = ("wear_score", "kl_raw", "kl_weighted")
    assert spans.slack("joint", inputs, monitoring, 42.0) is None                 # inside the span
    assert spans.slack("joint", inputs, monitoring, None) is None                 # no temperature
    assert spans.slack("joint", inputs, SimpleNamespace(state="learning", stage="warm-up"), 60.0) is None
    assert spans.slack("wear", ("wear_score",), monitoring, 60.0) is None         # no span learned
    assert spans.slack("joint", inputs, monitoring, 54.0) == pytest.approx((0.0, 0.21 * 3.0, 0.27 * 3.0))
    assert spans.slack("joint", inputs, monitoring, 36.0) == pytest.approx((0.0, 0.42, 0.54))    # 4 °C colder
    assert NominalSpans({"kl_raw": Span(40.0, 45.0)}).slack("kl_raw", ("kl_raw",), monitoring, 60.0) is None


def test_the_slack_survives_a_restart_and_bad_values_are_refused() -> None:
    bank, rng, cycle = _bank(4, temperature_slack=SLACK)
    restored = DetectorBank(bank.config, {})
    restored.load_state(json.loads(json.dumps(bank.state_dict(), allow_nan=False)), 0)
    monitoring = restored.detectors["kl_raw"]
    top = restored.spans.learned["kl_raw"].hi
    assert restored.spans.slack("kl_raw", ("kl_raw",), monitoring, top + 9.0) == pytest.approx((0.63,))
    for bad in (-0.1, 3.5, "0.2", float("nan"), True):
        with pytest.raises(ConfigError, match=r"decision\.temperature_slack\.kl_raw"):
            DecisionConfig(temperature_slack={"kl_raw": bad})
    with pytest.raises(ConfigError, match=r"decision\.temperature_slack\.kl_rwa"):
        DecisionConfig(temperature_slack={"kl_rwa": 0.2})
