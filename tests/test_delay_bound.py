"""The oracle CUSUM of the delay study (studies/delay_bound.py) on synthetic per-cycle values: it finds a known
shift about when theory says, and stays quiet without one."""

from __future__ import annotations

import math

import numpy as np

from studies.delay_bound import SITUATIONS, oracle_alarm, scenario


def _rows(values: np.ndarray, first: int = 0) -> list[dict]:
    return [{"cycle": first + k, "wear_score": float(v[0]), "kl_raw": math.exp(v[1]), "kl_weighted": math.exp(v[2])}
            for k, v in enumerate(values)]


def test_the_oracle_finds_a_known_shift_and_nothing_else():
    """Healthy values N(0, I) in 3-d, the worn run the same values plus a 1.5 σ shift on every axis from cycle
    600: the log-likelihood ratio gains d·δ²/2 = 3·1.125 = 3.4 nats a cycle on average, so log(2.6e6) = 14.8 nats
    take ≈ 4.4 cycles (the alarm is allowed up to 15, the noise of 4 cycles' sums: sd √(3·1.5²·4) = 5.2 nats);
    without the shift the CUSUM, thresholded at log ARL0, stays below it over 1 000 cycles (its run length to a
    false alarm is at least ARL0 = 2.6e6)."""
    rng = np.random.default_rng(1)
    healthy = rng.normal(0.0, 1.0, (1000, 3))
    worn = healthy.copy()
    worn[600:] += 1.5
    alarm = oracle_alarm(_rows(healthy), _rows(worn), 600, 2.6e6)
    assert alarm is not None and 600 <= alarm <= 615
    assert oracle_alarm(_rows(healthy), _rows(healthy), 600, 2.6e6) is None


def test_the_scenarios_hold_the_wear_on_joints_0_to_3_only():
    import tomllib

    for situation in SITUATIONS:
        worn = tomllib.loads(scenario(situation, worn=True).read_text())
        healthy = tomllib.loads(scenario(situation, worn=False).read_text())
        assert [j["index"] for j in worn["joint"]] == [0, 1, 2, 3] and "joint" not in healthy
        assert worn["simulation"] == healthy["simulation"] and worn.get("timeline") == healthy.get("timeline")
