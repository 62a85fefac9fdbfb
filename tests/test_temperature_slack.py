"""The temperature slack (edge_monitor/pipeline/temperature_slack.py): while the joint's temperature is d °C
outside the span a detector's nominal was learned in, the detector keeps testing, its value less its joint's
learned law a·√d (plus a margin), instead of holding. Both sides: a healthy drift — also one far beyond the
fleet's typical one, which the joint's own law learns — stays quiet, a wear shift alarms, and without the slack
the same healthy drift alarms (docs/DETECTION.md, "Watching while the joint warms")."""

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
from edge_monitor.pipeline.temperature_slack import HUBER, MARGIN_SDS, SlackLaw, SlackProfile

#: Where the warm-up nominals are learned, and the cycle-mean motor temperature's scatter [°C].
COLD, NOISE = 35.0, 3.0
#: How far the joint warms beyond that (the simulator's joints warm ≈ 25 °C).
WARMING = 25.0
PRIOR = {"wear_score": (0.0, 0.0), "kl_raw": (0.10, 0.13), "kl_weighted": (0.16, 0.13)}
KL = ("kl_raw", "kl_weighted", "joint")
#: Target run length: over the 200 monitored cycles of a test, 4 detectors expect 4·200/1e5 = 0.008 false alarms.
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


def _warm_run(bank: DetectorBank, rng: np.random.Generator, cycle: int, a: float, cycles: int = 200,
              wear: float = 0.0, wear_from: int = 150) -> tuple[set[str], list[dict]]:
    """The joint warms to COLD + WARMING over 100 cycles (the simulator's joints: ≈ 600); its KL inputs drift
    a·√d σ (d the excess over the span), and ``wear`` σ more on every input from cycle ``wear_from`` on."""
    top = max(bank.spans.learned[q].hi for q in KL)
    raised, decisions = set(), []
    for k in range(cycles):
        temperature = COLD + WARMING * min(1.0, k / 100)
        bank.observe_temperature(temperature + rng.normal(0.0, NOISE))
        shift = a * math.sqrt(max(0.0, temperature - top)) + (wear if k >= wear_from else 0.0)
        decided, alarms = bank.update(_inputs(rng, {"kl_raw": shift, "kl_weighted": shift,
                                                     "wear_score": wear if k >= wear_from else 0.0}), "r", 0, cycle + k)
        decisions.append(decided)
        raised |= {a.quantity for a in alarms}
    return raised, decisions


def test_a_healthy_warming_joint_is_watched_every_cycle_and_stays_quiet() -> None:
    """The KL inputs drift 0.6·√d σ (the steepest law measured on healthy default robots, 3.8 σ of the fleet's
    spread above its mean: 2.7 σ at 20 °C above the span): the joint's own law is learned while it warms, no
    alarm, and every detector tests every cycle (no hold)."""
    bank, rng, cycle = _bank(1, temperature_slack=PRIOR)
    raised, decisions = _warm_run(bank, rng, cycle, a=0.6)
    assert raised == set()
    assert all(d[q].statistic is not None and not d[q].reason.startswith("held") for d in decisions for q in d)
    assert set(bank.reasons.values()) == {"tested"}
    learned = bank.spans.profiles["kl_raw"].laws["warm"]
    assert learned.mean[0] == pytest.approx(0.6, abs=4 * learned.sd[0] + 0.05)


def test_without_the_slack_the_same_healthy_drift_alarms() -> None:
    """The other side: the same 0.6·√d drift with no slack is 2.5 σ beyond the allowance once warm: the KL
    detectors cross their thresholds."""
    bank, rng, cycle = _bank(2, temperature_slack={q: (0.0, 0.0) for q in PRIOR})
    raised, _ = _warm_run(bank, rng, cycle, a=0.6)
    assert {"kl_raw", "kl_weighted"} <= raised


def test_wear_on_a_warm_joint_alarms_through_the_learned_slack() -> None:
    """A 4 σ shift on every input once the joint is warm and its law learned (critical wear moves the log KL
    distances 4–5 σ on the simulated joints) on top of the typical 0.16·√d drift: every detector alarms (one
    cycle's innovation enters the law clipped to 2 σ, so the law follows a step slowly)."""
    bank, rng, cycle = _bank(3, temperature_slack=PRIOR)
    raised, _ = _warm_run(bank, rng, cycle, a=0.16, wear=4.0)
    assert {"wear", "kl_raw", "kl_weighted", "joint"} <= raised


def test_the_law_learns_a_known_slope_and_a_step_pulls_it_little() -> None:
    """z = 0.4·√d + N(0, 1) over d = 1 … 25 °C (200 cycles): â is within 4 of its standard deviations
    (1/√(1/0.13² + Σd) = 0.014) of 0.4. A 5 σ step afterwards moves â by at most HUBER·√d/precision a cycle."""
    rng = np.random.default_rng(4)
    law = SlackLaw([(0.10, 0.13)])
    assert law.slack(4.0)[0] == pytest.approx((0.10 + MARGIN_SDS * 0.13) * 4.0)        # 16 °C out: x = √16
    ds = np.linspace(1.0, 25.0, 200)
    for d in ds:
        law.update(math.sqrt(d), [0.4 * math.sqrt(d) + rng.normal()])
    sd = 1.0 / math.sqrt(1 / 0.13 ** 2 + ds.sum())
    assert law.sd[0] == pytest.approx(sd) and law.mean[0] == pytest.approx(0.4, abs=4 * sd)
    before, precision = law.mean[0], law.precision[0]
    law.update(5.0, [0.4 * 5.0 + 5.0])
    assert 0 < law.mean[0] - before <= HUBER * 5.0 / precision + 1e-12


def test_spans_say_the_side_and_distance_and_the_profiles_survive_a_restart() -> None:
    spans = NominalSpans({"joint": Span(40.0, 45.0)}, slack_prior=PRIOR)
    monitoring = SimpleNamespace(state="monitoring", stage="warm-up")
    assert spans.outside("joint", monitoring, 42.0)[1] == 0.0                 # inside the span
    assert spans.outside("joint", monitoring, 54.0) == ("warm", 9.0)
    assert spans.outside("joint", monitoring, 36.0) == ("cold", 4.0)
    assert spans.outside("joint", SimpleNamespace(state="learning", stage="warm-up"), 60.0) == ("warm", 0.0)
    inputs = ("wear_score", "kl_raw", "kl_weighted")
    assert spans.slack("joint", inputs, monitoring, 54.0) == pytest.approx((0.0, 0.36 * 3.0, 0.42 * 3.0))
    assert spans.slack("joint", inputs, monitoring, None) is None
    profile = SlackProfile([(0.1, 0.13), (0.0, 0.0)])
    profile.update("warm", 3.0, [2.0, 5.0])
    again = SlackProfile.from_state([(0.1, 0.13), (0.0, 0.0)], json.loads(json.dumps(profile.state_dict())))
    assert again.slack("warm", 3.0) == pytest.approx(profile.slack("warm", 3.0))
    assert SlackProfile.from_state([(0.1, 0.13)], {"warm": {"precision": [-1], "weighted": [0]}}).slack(
        "warm", 2.0) == pytest.approx(((0.1 + MARGIN_SDS * 0.13) * 2.0,))
    falling = SlackProfile([(0.1, 0.13)])
    for _ in range(200):
        falling.update("cold", 3.0, [-4.0])            # a law that says the values fall: no negative slack
    assert falling.slack("cold", 3.0) is None


def test_the_bank_keeps_its_learned_laws_over_a_restart_and_bad_priors_are_refused() -> None:
    bank, rng, cycle = _bank(5, temperature_slack=PRIOR)
    _warm_run(bank, rng, cycle, a=0.3, cycles=120)
    restored = DetectorBank(bank.config, {})
    restored.load_state(json.loads(json.dumps(bank.state_dict(), allow_nan=False)), 0)
    assert restored.spans.profiles["kl_raw"].state_dict() == bank.spans.profiles["kl_raw"].state_dict()
    for bad in ([0.1], [0.1, -0.2], ["0.1", 0.1], [float("nan"), 0.1], [5.0, 0.1]):
        with pytest.raises(ConfigError, match=r"decision\.temperature_slack\.kl_raw"):
            DecisionConfig(temperature_slack={"kl_raw": bad})
    with pytest.raises(ConfigError, match=r"decision\.temperature_slack\.kl_rwa"):
        DecisionConfig(temperature_slack={"kl_rwa": [0.1, 0.1]})


def test_a_steady_nominal_keeps_the_warm_up_law_re_anchored() -> None:
    """The steady nominal is learned warm, but the KL distances are still measured against the joint's first
    cycles: 5 °C above a steady span that lies 17 °C above the warm-up span the law says √22 − √17 = 0.57 √°C,
    not √5 = 2.24. A maintenance (a new warm-up nominal) starts from the prior again."""
    spans = NominalSpans({"kl_raw": Span(35.0, 38.0)}, slack_prior=PRIOR)
    warm_up = SimpleNamespace(state="monitoring", stage="warm-up", collecting=True)
    spans.profiles["kl_raw"] = SlackProfile([PRIOR["kl_raw"]])
    spans.profiles["kl_raw"].update("warm", 4.0, [1.5])
    learned = spans.profiles["kl_raw"].state_dict()
    steady = SimpleNamespace(state="monitoring", stage="steady", collecting=True)
    spans.track("kl_raw", steady, True, False, 52.0)        # the steady values …
    spans.track("kl_raw", steady, True, True, 55.0)         # … and the fit
    assert spans.learned["kl_raw"] == Span(52.0, 55.0) and spans.origins["kl_raw"] == 38.0
    assert spans.profiles["kl_raw"].state_dict() == learned
    side, x = spans.regressor("kl_raw", steady, 60.0)
    assert side == "warm" and x == pytest.approx(math.sqrt(22.0) - math.sqrt(17.0))
    assert spans.regressor("kl_raw", steady, 42.0) == ("cold", pytest.approx(math.sqrt(10.0)))
    again = NominalSpans.from_state(json.loads(json.dumps(spans.state_dict())), slack_prior=PRIOR,
                                    inputs={"kl_raw": ("kl_raw",)})
    assert again.origins == {"kl_raw": 38.0} and again.profiles["kl_raw"].state_dict() == learned
    spans.clear()
    spans.track("kl_raw", warm_up, True, True, 36.0)
    assert "kl_raw" not in spans.origins and "kl_raw" not in spans.profiles
