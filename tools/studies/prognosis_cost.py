#!/usr/bin/env python3
"""What the prognosis costs per joint (docs/BENCHMARKS.md, "Prognosis"): its memory after N cycles (the
saved state's JSON size and the Python heap the joint's prognosis holds, by tracemalloc) — constant in N —
and its CPU time per cycle, for each trend model, next to the same run's per-cycle wear estimate (the
agent's costliest per-cycle step before it) as the baseline.

Usage: ``python tools/studies/prognosis_cost.py [--cycles 100,1000,10000,100000] [--repeat 2000]``.
"""

from __future__ import annotations

import os

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")     # CPU time of one thread: tiny matrices, no BLAS threads

import argparse  # noqa: E402
import dataclasses  # noqa: E402
import gc  # noqa: E402
import json  # noqa: E402
import sys  # noqa: E402
import time  # noqa: E402
import tracemalloc  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))

from edge_monitor.features.prognosis import JointPrognosis, PrognosisConfig  # noqa: E402
from edge_monitor.features.wear_estimation import WearEstimator  # noqa: E402
from edge_monitor.stats.wear_trend import TREND_MODELS  # noqa: E402
from joint_model.friction import friction_magnitude  # noqa: E402

SPEEDS = np.array([2.1, 8.7, 15.3, 21.9, 28.5, 35.1, 41.7, 82.2, 133.5, 184.7, 236.2, 287.1])


def series(n: int, seed: int = 3) -> np.ndarray:
    """A wearing joint's estimates: 0.02 per cycle from 5, noise of std 6.5 (what the study's joints show)."""
    rng = np.random.default_rng(seed)
    return 5.0 + 0.02 * np.arange(n) + rng.normal(0.0, 6.5, n)


def run(config: PrognosisConfig, values: np.ndarray) -> JointPrognosis:
    prognosis = JointPrognosis(config, 35.0)
    for k, value in enumerate(values):
        prognosis.update(k, float(value), 5.0, use=True, alarm=True, cycles_per_day=300.0)
    return prognosis


def memory(config: PrognosisConfig, cycles: list[int]) -> list[dict]:
    out = []
    for n in cycles:
        gc.collect()
        tracemalloc.start()
        before = tracemalloc.take_snapshot()
        prognosis = JointPrognosis(config, 35.0)
        for k, value in enumerate(series(n)):
            prognosis.trend.update(k, float(value), 5.0)       # the state alone: forecasts leave nothing behind
        gc.collect()
        held = sum(s.size_diff for s in tracemalloc.take_snapshot().compare_to(before, "filename"))
        tracemalloc.stop()
        out.append({"cycles": n, "state_json_bytes": len(json.dumps(prognosis.state_dict())), "heap_bytes": held})
    return out


def per_cycle_us(config: PrognosisConfig, repeat: int) -> float:
    """CPU µs of one ``update`` (trend + forecast) of a joint that forecasts, after its first 300 cycles."""
    prognosis = run(config, series(300))
    values = series(300 + repeat)[300:]
    started = time.process_time()
    for k, value in enumerate(values):
        prognosis.update(300 + k, float(value), 5.0, use=True, alarm=True, cycles_per_day=300.0)
    return (time.process_time() - started) / repeat * 1e6


def wear_estimate_us(repeat: int) -> float:
    """CPU µs of the per-cycle wear estimate at the 12 default speeds (the same run's baseline)."""
    estimator = WearEstimator(temperature_range=(30.0, 80.0), method="marginal")
    torque = friction_magnitude(SPEEDS, 0.5, 45.0, 20.0)
    started = time.process_time()
    for _ in range(repeat):
        estimator.estimate(SPEEDS, torque, 0.5, 0.1)
    return (time.process_time() - started) / repeat * 1e6


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--cycles", default="100,1000,10000,100000")
    parser.add_argument("--repeat", type=int, default=2000)
    args = parser.parse_args(argv)
    cycles = [int(c) for c in args.cycles.split(",")]
    baseline = wear_estimate_us(max(args.repeat // 4, 50))
    print(f"wear estimate (baseline, same run): {baseline:.0f} µs per cycle")
    print(f"{'model':<14} {'µs/cycle':>9} {'× wear estimate':>15}   state JSON bytes / heap bytes after " +
          ", ".join(f"{n}" for n in cycles) + " cycles")
    for model in TREND_MODELS:
        config = dataclasses.replace(PrognosisConfig(), model=model)
        cost = per_cycle_us(config, args.repeat)
        sizes = memory(config, cycles)
        print(f"{model:<14} {cost:>9.0f} {cost / baseline:>15.2f}   " +
              ", ".join(f"{m['state_json_bytes']}/{m['heap_bytes']}" for m in sizes))
    return 0


if __name__ == "__main__":
    sys.exit(main())
