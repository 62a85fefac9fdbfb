"""tools/arl_study.py's measurement of run lengths on real series (the renewal the agent study uses)."""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent / "tools"))

from arl_study import real_run_lengths  # noqa: E402

from edge_monitor.stats.sequential_detector import DetectorConfig  # noqa: E402


def test_run_lengths_renew_after_each_crossing_and_count_only_monitored_cycles() -> None:
    """400 values, a +6σ step at 100: the first detector (learned on 0–59) crosses a moderate
    threshold once, soon after the step; the relearned one (on shifted values only) never does. So
    cycles / crossings = 400 − 2 × 60 learning cycles = 280, whatever the crossing cycle; a threshold
    no statistic reaches leaves the run length infinite (no crossing)."""
    rng = np.random.default_rng(4)
    x = rng.normal(size=(400, 1))
    x[100:] += 6.0
    config = DetectorConfig(density="gauss", n_nominal=60, window=50, direction="increase", allowance=0.0)
    run_lengths = real_run_lengths([x], config, np.array([5.0, 1e6]))
    assert run_lengths[0] == 280.0
    assert np.isinf(run_lengths[1])
