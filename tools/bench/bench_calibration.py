#!/usr/bin/env python3
"""CPU time of one detector's threshold calibration (ARL0 = 10⁴), the shipped paths against the previous
ones, all in this process (docs/BENCHMARKS.md, "Threshold calibration per detector").

Rows (each a fresh ``calibrate()`` call, CPU time of this process with ``time.process_time``; caches
cleared before each so nothing is reused):

* scalar Gaussian, warm-up (60 values, at the allowance boundary) and steady (240 values, for the
  healthy drift and wander after learning of the wear score and of the KL distances): read from the
  shipped table (:mod:`edge_monitor.stats.threshold_table`);
* scalar Gaussian with settings outside the table (50 values): simulated in standard units;
* joint vector (3-d Gaussian with the correlations of a healthy joint's inputs), warm-up and steady:
  read from the shipped table by the correlation of its KL axes; at settings outside the table (at
  the nominal): simulated in standard units for its correlation matrix;
* before: the GCE warm-up nominal (60 values, 48 bootstrap detectors with a GCE refitted per nominal),
  the 3-d KDE warm-up nominal, and the steady stage simulated from the 240 values (smoothed bootstrap,
  48 detectors of the general mixture code).

Usage: ``python tools/bench/bench_calibration.py [--json OUT]``; a few minutes.
"""

from __future__ import annotations

import os

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import argparse  # noqa: E402
import json  # noqa: E402
import sys  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402
from typing import Any, Callable  # noqa: E402

import numpy as np  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))

from edge_monitor.stats import gaussian_calibration, threshold_table  # noqa: E402
from edge_monitor.stats.calibration import calibrate  # noqa: E402

#: Correlations of (wear score, log kl_raw, log kl_weighted) of a healthy joint (docs/DETECTION.md).
JOINT_CORRELATION = np.array([[1.0, 0.03, 0.19], [0.03, 1.0, 0.67], [0.19, 0.67, 1.0]])
COMMON: dict[str, Any] = dict(window=100, arl0=1e4, direction="increase", allowance=0.75, clip_sigma=3.0)


def _values(n: int, d: int, seed: int = 0) -> np.ndarray:
    rng = np.random.default_rng(seed)
    chol = np.linalg.cholesky(JOINT_CORRELATION[:d, :d])
    return rng.standard_normal((n, d)) @ chol.T


def _timed(call: Callable[[], Any]) -> tuple[float, Any]:
    gaussian_calibration.simulate.cache_clear()
    threshold_table.entries_by_key.cache_clear()
    started = time.process_time()
    result = call()
    return time.process_time() - started, result


CASES: list[tuple[str, Callable[[], Any]]] = [
    ("scalar, warm-up (Gaussian, 60 values, boundary): table",
     lambda: calibrate(_values(60, 1), "gauss", at="boundary", **COMMON)),
    ("scalar, steady wear (Gaussian, 240 values, healthy drift 0.00 ± 0.08 σ): table",
     lambda: calibrate(_values(240, 1), "gauss", at="healthy_drift", drift_mean=(0.0,), drift_sd=(0.08,), **COMMON)),
    ("scalar, steady kl_weighted (Gaussian, 240 values, healthy drift 0.18 ± 0.195 σ, wander 9 %): table",
     lambda: calibrate(_values(240, 1), "gauss", at="healthy_drift", drift_mean=(0.18,), drift_sd=(0.195,),
                       wander=(0.09,), **COMMON)),
    ("scalar outside the table (Gaussian, 50 values): simulated",
     lambda: calibrate(_values(50, 1), "gauss", at="boundary", **COMMON)),
    ("joint vector, steady (Gaussian 3-d, 240 values, healthy drift and wander): table",
     lambda: calibrate(_values(240, 3), "gauss", at="healthy_drift", drift_mean=(0.0, 0.11, 0.24),
                       drift_sd=(0.08, 0.14, 0.21), wander=(0.0, 0.09, 0.09), **COMMON)),
    ("joint vector, warm-up (Gaussian 3-d, 60 values, boundary): table",
     lambda: calibrate(_values(60, 3), "gauss", at="boundary", **COMMON)),
    ("joint vector outside the table (Gaussian 3-d, 240 values, at the nominal): simulated",
     lambda: calibrate(_values(240, 3), "gauss", at="nominal", **COMMON)),
    ("before: scalar warm-up (GCE, 60 values, boundary, 48 detectors)",
     lambda: calibrate(_values(60, 1), "gce", at="boundary", **COMMON)),
    ("before: joint vector warm-up (KDE 3-d, 60 values, boundary, 48 detectors)",
     lambda: calibrate(_values(60, 3), "kde", at="boundary", **COMMON)),
    ("before: scalar steady (from the 240 values, 48 detectors)",
     lambda: calibrate(_values(240, 1), "gauss", at="nominal", simulate_from="values", **COMMON)),
    ("before: joint vector steady (from the 240 values, 48 detectors)",
     lambda: calibrate(_values(240, 3), "gauss", at="nominal", simulate_from="values", **COMMON)),
]


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--json", type=Path)
    args = parser.parse_args(argv)
    rows = []
    print("| calibration | CPU [s] | threshold [nats] | ± [nats] | method |")
    print("|---|---|---|---|---|")
    for name, call in CASES:
        cpu, result = _timed(call)
        se = "—" if result.h_se is None else f"{result.h_se:.3f}"
        print(f"| {name} | {cpu:.2f} | {result.threshold:.3f} | {se} | {result.method} |", flush=True)
        rows.append({"case": name, "cpu_s": cpu, "threshold": result.threshold, "h_se": result.h_se,
                     "method": result.method})
    if args.json:
        args.json.write_text(json.dumps(rows, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
