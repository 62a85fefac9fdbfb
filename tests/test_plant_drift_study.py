"""tools/studies/plant_drift_study.py: the per-period drift of the steady detectors' inputs and the pooled drift the
steady calibration is given, on hand-made standard-unit values."""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).resolve().parent.parent / "tools" / "studies"))

from plant_drift_study import STEADY_NOMINAL, input_summary, period_of  # noqa: E402


def _rows(seed: int, shifts: tuple[float, float], joints: int = 40, per_period: int = 600
          ) -> list[tuple[str, tuple[int, int], int, float]]:
    """``joints`` joints of independent N(shift, 1) values: ``per_period`` cycles before cycle 2 000 at
    ``shifts[0]``, as many from 2 000 at ``shifts[1]``."""
    rng = np.random.default_rng(seed)
    rows = []
    for joint in range(joints):
        for k in range(2 * per_period):
            cycle = 1400 + k
            rows.append(("kl_weighted", (seed, joint), cycle, float(rng.normal(shifts[cycle >= 2000], 1.0))))
    return rows


def test_a_shift_in_one_period_is_seen_there_and_pooled_by_its_cycles() -> None:
    """No drift before cycle 2 000, +0.3 σ after, equal cycles: each period's mean is found (within 4 standard
    errors of 40 joints' means of 600 values), the pooled mean is 0.15 and the pooled spread beyond the
    noise is the periods' ±0.15 (the noise subtracted is the learning error of a 240-value nominal, which
    these values do not have, so the spread comes out a little low: within 0.05); independent values have
    variance ratios ≈ 1. Other side: without the shift, no drift and (almost) no spread."""
    summary = input_summary(_rows(1, (0.0, 0.3)), "kl_weighted", [2000])
    (before, _), (after, _) = summary["periods"]
    se = 1.0 / np.sqrt(600 * 40)
    assert before == pytest.approx(0.0, abs=4 * se) and after == pytest.approx(0.3, abs=4 * se)
    mean, sd = summary["drift"]
    assert mean == pytest.approx(0.15, abs=4 * se)
    assert sd == pytest.approx(0.15, abs=0.05)
    assert all(r == pytest.approx(1.0, abs=0.25) for r in summary["ratios"])
    flat = input_summary(_rows(2, (0.0, 0.0)), "kl_weighted", [2000])
    assert flat["drift"][0] == pytest.approx(0.0, abs=4 * se) and flat["drift"][1] < 0.05
    assert input_summary(flat_rows := _rows(3, (0.0, 0.0), joints=2), "wear", [2000])["periods"] == [None, None]
    assert flat_rows and np.isnan(input_summary(flat_rows, "wear", [2000])["drift"][0])   # no such input: no number


def test_periods_are_split_at_their_first_cycle() -> None:
    assert [period_of(c, [2000, 2600]) for c in (0, 1999, 2000, 2599, 2600, 5000)] == [0, 0, 1, 1, 2, 2]
    assert STEADY_NOMINAL == 240
