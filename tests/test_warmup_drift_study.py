"""tools/studies/warmup_drift_study.py: the drift measure, and the physics that sets kl.min_speed."""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent / "tools" / "studies"))

from warmup_drift_study import drift_rows, residual  # noqa: E402


def test_shift_and_spread_are_in_units_of_the_learned_nominal() -> None:
    """A quantity learned as N(0, 1) over 60 cycles, then moved by +0.5 with half the spread, reads
    shift ≈ +0.5 (within 4 standard errors of the window and learning means) and spread ≈ 0.5."""
    rng = np.random.default_rng(3)
    n = 60 + 2 * 100
    values = np.concatenate([rng.normal(0.0, 1.0, 60), rng.normal(0.5, 0.5, 200)])
    series = {"cycle": np.arange(n, dtype=float), "temperature": np.linspace(30, 50, n),
              "wear_score": values, "kl_raw": values.copy(), "kl_weighted": -values}
    rows = drift_rows(series, window=100, n_nominal=60)
    assert [r["first_cycle"] for r in rows] == [60, 160]
    learned = values[:60]
    for row in rows:
        scale = learned.std(ddof=1)
        tolerance = 4 * np.hypot(1 / np.sqrt(60), 0.5 / np.sqrt(100)) / scale
        shift = (0.5 - learned.mean()) / scale
        assert abs(row["kl_raw"]["shift"] - shift) < tolerance
        assert abs(row["kl_weighted"]["shift"] + shift) < tolerance
        assert 0.35 < row["wear_score"]["spread"] < 0.7
        assert row["learned_temperature"][0] == 30.0


def test_temperature_compensation_is_exact_above_10_rad_s_and_not_below_5() -> None:
    """The same simulated cycle at 35 and 55 °C, the warm one moved to 35 °C with the exact model: the
    residual is a small fraction of the uncompensated difference above 10 rad/s (the KL keeps those
    samples) and no smaller than half of it below 5 rad/s (it leaves them out)."""
    bands = {(r["speed_from"], r["speed_to"]): r for r in residual()}
    for (lo, _), row in bands.items():
        ratio = row["residual_rms"] / row["uncompensated_rms"]
        if lo >= 10.0:
            assert ratio < 0.15, (lo, ratio)
        elif lo < 5.0:
            assert ratio > 0.5, (lo, ratio)


def test_causes_recover_a_drift_made_of_one_parameter_and_see_none_in_noise() -> None:
    """Joints whose late kl_raw shift is 10 × their fvξ deviation give correlation 1 with fvξ and R² 1
    on (fsξ, fvξ); a wear score made of noise gives a small R²; the joints' variation comes from the
    simulator (the same factors every time for a seed, within its ±8 %)."""
    from warmup_drift_study import VARIED_PARAMS, causes, joint_variation

    from sim_controller.config import SimConfig

    variation = joint_variation(SimConfig(joints=6, seed=5)) + joint_variation(SimConfig(joints=6, seed=6))
    assert variation[:6] == joint_variation(SimConfig(joints=6, seed=5))
    assert all(abs(v) <= 0.08 + 1e-9 for joint in variation for v in joint.values())
    noise = np.random.default_rng(1).normal(size=len(variation))
    per_joint = [{"variation": v, "windows": [
        {q: {"shift": 0.0} for q in ("wear_score", "kl_raw", "kl_weighted")},
        {"kl_raw": {"shift": 10 * v["fvxi"]}, "kl_weighted": {"shift": 0.0}, "wear_score": {"shift": float(e)}}]}
        for v, e in zip(variation, noise)]
    out = causes(per_joint)
    assert out["kl_raw"]["corr"]["fvxi"] == 1.0 and out["kl_raw"]["r2_temperature_coefficients"] == 1.0
    assert out["wear_score"]["r2_temperature_coefficients"] < 0.5
    assert out["kl_weighted"]["r2_temperature_coefficients"] is None       # no spread to explain
    assert set(out["kl_raw"]["corr"]) == set(VARIED_PARAMS)


def test_variant_friction_sets_one_parameter_at_a_time() -> None:
    """``fvxi``: the base table with only fvξ as drawn; ``all_but_fvxi``: as drawn except fvξ; a name
    that is not varied is a clear error."""
    import pytest
    from warmup_drift_study import variant_friction

    from sim_controller.config import SimConfig

    config = SimConfig(joints=3, seed=7)
    drawn, base = variant_friction(config, 2, "drawn"), variant_friction(config, 2, "base")
    assert base == config.friction and drawn != base
    one = variant_friction(config, 2, "fvxi")
    assert one.fvxi == drawn.fvxi and one.fv0 == base.fv0
    others = variant_friction(config, 2, "all_but_fvxi")
    assert others.fvxi == base.fvxi and others.fv0 == drawn.fv0
    with pytest.raises(ValueError, match="variant 'tau'"):
        variant_friction(config, 2, "tau")
