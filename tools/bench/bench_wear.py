#!/usr/bin/env python3
"""Benchmark: per-cycle wear estimation time (issue 4 target: ≤ 50 ms per call per joint).

Cycles from the §3 model (ξ ~ U(30, 50), τl ~ N(0.5, 0.1²), ϖ ~ U(0, 60), σ = 5.7e-3) at the design
speeds N = 1…4 and at the 12 default speeds. Reports wall and CPU time per call (mean, p99, max)
for both methods, and, as a same-process baseline, the textbook solver of the same N ≥ 2 problem:
``scipy.optimize.minimize`` (L-BFGS-B, finite-difference gradient) of rᵀΣ⁻¹r from the centre of
the box, without a start grid — with how often it ends at a worse cost than ours (local minima).

Usage: .venv/bin/python tools/bench/bench_wear.py [--cycles 200] [--out docs/benchmarks/wear.md]
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from pathlib import Path

import numpy as np
from scipy.optimize import minimize

from edge_monitor.features.wear_estimation import WearEstimator
from edge_monitor.features.wear_information import data_covariance
from edge_monitor.offline.experiment_design import design_speeds
from joint_model import DEFAULT_SPEED_LEVELS, FRICTION_NOISE_STD, friction_magnitude

DEFAULT_SPEEDS = list(DEFAULT_SPEED_LEVELS)
LOAD_MEAN, LOAD_STD = 0.5, 0.1
BUDGET_MS = 50.0


def cycles(speeds: list[float], n: int, seed: int) -> np.ndarray:
    rng = np.random.default_rng(seed)
    v = np.asarray(speeds)
    xi, load, wear = rng.uniform(30, 50, n), rng.normal(LOAD_MEAN, LOAD_STD, n), rng.uniform(0, 60, n)
    return (friction_magnitude(v[None, :], load[:, None], xi[:, None], wear[:, None])
            + rng.normal(0, FRICTION_NOISE_STD, (n, v.size)))


def time_calls(fn, data: np.ndarray) -> tuple[np.ndarray, np.ndarray, list]:
    wall, cpu, out = np.empty(len(data)), np.empty(len(data)), []
    for k, row in enumerate(data):
        t0, c0 = time.perf_counter(), time.process_time()
        out.append(fn(row))
        wall[k], cpu[k] = time.perf_counter() - t0, time.process_time() - c0
    return 1e3 * wall, 1e3 * cpu, out


def baseline_solver(speeds: list[float]):
    v = np.asarray(speeds)
    cov_inv = np.linalg.inv(data_covariance(v, LOAD_STD, FRICTION_NOISE_STD))

    def cost(theta, tau):
        r = tau - friction_magnitude(v, LOAD_MEAN, theta[0], theta[1])
        return float(r @ cov_inv @ r)

    def solve(tau):
        fit = minimize(cost, x0=[40.0, 35.0], args=(tau,), method="L-BFGS-B", bounds=[(30, 50), (0, 100)])
        return fit.fun

    return solve, cost


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--cycles", type=int, default=200)
    parser.add_argument("--out", type=Path, default=Path("docs/benchmarks/wear.md"))
    args = parser.parse_args(argv)
    configs = [(f"N={n} design", design_speeds(n).speeds) for n in (1, 2, 3, 4)]
    configs.append(("N=12 default", DEFAULT_SPEEDS))
    rows = []
    for i, (name, speeds) in enumerate(configs):
        data = cycles(speeds, args.cycles, seed=i)
        for method in (("marginal",) if len(speeds) == 1 else ("joint", "marginal")):
            est = WearEstimator(method=method)
            wall, cpu, results = time_calls(lambda t: est.estimate(speeds, t, LOAD_MEAN, LOAD_STD), data)
            row = {"config": name, "method": method, "wall_mean": wall.mean(), "wall_p99": np.quantile(wall, 0.99),
                   "wall_max": wall.max(), "cpu_mean": cpu.mean(), "cpu_p99": np.quantile(cpu, 0.99),
                   "baseline": "", "worse": ""}
            if method == "joint":
                solve, cost = baseline_solver(speeds)
                b_wall, b_cpu, b_cost = time_calls(solve, data)
                ours = np.array([cost([r.temperature, r.estimate], t) for r, t in zip(results, data)])
                row["baseline"] = f"{b_cpu.mean():.2f} ms CPU → ratio ours/baseline {cpu.mean() / b_cpu.mean():.2f}"
                row["worse"] = f"{100 * np.mean(np.array(b_cost) > ours + 1e-6):.0f} %"
            rows.append(row)
            print(f"{name:14s} {method:8s} wall {row['wall_mean']:.2f} ms (p99 {row['wall_p99']:.2f}, "
                  f"max {row['wall_max']:.2f})  CPU {row['cpu_mean']:.2f} ms (p99 {row['cpu_p99']:.2f})  "
                  f"{row['baseline']} {row['worse']}", flush=True)
    load = os.getloadavg()[0]
    lines = ["## Wear estimation (per cycle, per joint)", "",
             f"`tools/bench/bench_wear.py --cycles {args.cycles}`; budget {BUDGET_MS:.0f} ms per call. Load average "
             f"during the run: {load:.1f} on {os.cpu_count()} cores (shared machine: wall times include waiting; "
             "CPU time is the estimator's own cost). Baseline, same process: L-BFGS-B on rᵀΣ⁻¹r from the box "
             "centre, no start grid; 'baseline worse' = cycles where it ends at a higher cost than ours.", "",
             "| speeds | method | CPU ms mean | CPU ms p99 | wall ms mean | wall ms p99 | wall ms max | "
             "CPU p99 / budget | baseline (CPU) | baseline worse |", "|---|---|---|---|---|---|---|---|---|---|"]
    for r in rows:
        lines.append(f"| {r['config']} | {r['method']} | {r['cpu_mean']:.2f} | {r['cpu_p99']:.2f} | "
                     f"{r['wall_mean']:.2f} | {r['wall_p99']:.2f} | {r['wall_max']:.2f} | "
                     f"{r['cpu_p99'] / BUDGET_MS:.2f} | {r['baseline'] or '—'} | {r['worse'] or '—'} |")
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text("\n".join(lines) + "\n", encoding="utf-8")
    print(f"written {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
