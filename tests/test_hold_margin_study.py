"""tools/studies/hold_margin_study.py: the drift of a joint's KL distance binned by how far its smoothed temperature
is above its learning span, and the raw hold it replaced, on hand-made series."""

from __future__ import annotations

import math
import sys
from pathlib import Path

import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).resolve().parent.parent / "tools" / "studies"))

from hold_margin_study import ALLOWANCE, drift_table, joint_rows  # noqa: E402


def _rows(temperature: np.ndarray, log_kl: np.ndarray) -> list[dict[str, float]]:
    return [{"cycle": float(c), "motor_temperature": float(t), "kl_weighted": float(math.exp(y))}
            for c, (t, y) in enumerate(zip(temperature, log_kl))]


def test_a_joint_whose_kl_drifts_with_its_warming_lands_in_the_bins_it_warmed_through() -> None:
    """60 learning cycles at 40 °C (log KL N(0, 1)), then 40 cycles each 3, 7 and 12 °C warmer with the log
    KL 0.1, 0.5 and 1.0 σ up: each block's shift lands in its bin (without scatter each step is a jump the
    smoothing follows at once), beyond the allowance only at 12 °C; the raw hold (its span 40 … 40, margin
    2 °C) held every one of those cycles."""
    rng = np.random.default_rng(0)
    learn = rng.normal(0.0, 1.0, 60)
    learn = (learn - learn.mean()) / learn.std(ddof=1)            # exactly the learned mean 0, std 1
    temperature = np.concatenate([np.full(60, 40.0), np.full(40, 43.0), np.full(40, 47.0), np.full(40, 52.0)])
    log_kl = np.concatenate([learn, np.full(40, 0.1), np.full(40, 0.5), np.full(40, 1.0)])
    rows = joint_rows(_rows(temperature, log_kl), "kl_weighted", 60, until=10_000)
    assert len(rows) == 120
    table = {tuple(r["bin"]): r for r in drift_table([rows])}
    assert table[(2.0, 4.0)]["mean"] == pytest.approx(0.1, abs=0.15)
    assert table[(6.0, 8.0)]["mean"] == pytest.approx(0.5, abs=0.15)
    assert table[(10.0, 14.0)]["mean"] == pytest.approx(1.0, abs=0.15)
    assert table[(10.0, 14.0)]["beyond_allowance"] == 1.0 and table[(6.0, 8.0)]["beyond_allowance"] == 0.0
    assert 1.0 > ALLOWANCE > 0.5
    assert all(table[b]["raw_hold_tested"] == 0.0 for b in ((2.0, 4.0), (6.0, 8.0), (10.0, 14.0)))
    assert table[(0.0, 2.0)]["cycles"] == 0 and table[(0.0, 2.0)]["mean"] is None
