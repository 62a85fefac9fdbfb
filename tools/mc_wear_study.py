#!/usr/bin/env python3
"""Monte Carlo quality study of the wear estimator (ALGORITHMS.md §3; issue 4 quality targets).

Data from the statistical model of §3, per cycle: ξ ~ U(30, 50) °C, τl ~ N(0.5, 0.1²) (the
estimator is given μl = 0.5, σl = 0.1), τ = τf(v; τl, ξ, ϖ) + N(0, σ²), σ = 5.7e-3; ϖ ∈ {0, 20, 35, 50};
speeds from ``design_speeds(N)`` (default design point ξ' = 40 °C, ϖ' = 35) for N = 1…4, and the
badly chosen pair 82/133 rad/s. For every configuration it reports the mean and variance of ϖ̂, the
bounds, the calibration of the published std, and the time per estimate; it writes a JSON file, a
markdown table and figures (matplotlib, optional) under docs/wear_estimation/.

Bounds reported:
* ``bound`` — 1/F of the temperature-marginalised likelihood (ξ a random nuisance ~ U(30, 50)):
  the Cramér–Rao bound that applies to this data model (what the factor-2 target is checked against);
* ``crlb_design`` — the local bound [F⁻¹]₂₂ at the design point (ξ = 40 °C, N ≥ 2);
* ``crlb_mean_true`` — the local bound at each cycle's true ξ, averaged (N ≥ 2).

Usage: .venv/bin/python tools/mc_wear_study.py [--runs 400] [--seed 0] [--out-dir docs/wear_estimation]
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import time
from pathlib import Path

import numpy as np

from edge_monitor.features.wear_estimation import WearEstimator, crlb_wear, marginal_fisher_wear
from edge_monitor.offline.experiment_design import design_speeds
from joint_model.friction import FRICTION_NOISE_STD, friction_magnitude

WEARS = (0.0, 20.0, 35.0, 50.0)
LOAD_MEAN, LOAD_STD = 0.5, 0.1
TEMPERATURE_RANGE = (30.0, 50.0)
BAD_SPEEDS = [82.0, 133.0]
Z_999 = 3.29  # two-sided 0.1 % normal quantile
BOUND_DRAWS = 4000  # MC draws of the marginal Fisher information (relative error ≈ √(2/4000) ≈ 2 %)


def simulate(speeds: list[float], wear: float, runs: int, rng: np.random.Generator):
    v = np.asarray(speeds, dtype=float)
    xi = rng.uniform(*TEMPERATURE_RANGE, runs)
    load = rng.normal(LOAD_MEAN, LOAD_STD, runs)
    noise = rng.normal(0.0, FRICTION_NOISE_STD, (runs, v.size))
    return friction_magnitude(v[None, :], load[:, None], xi[:, None], wear) + noise, xi


def study_config(estimator: WearEstimator, name: str, speeds: list[float], wear: float, runs: int,
                 seed: int) -> dict:
    """One (design, method, ϖ) configuration; the same seed gives the same cycles for both methods."""
    tau, xi = simulate(speeds, wear, runs, np.random.default_rng(seed))
    estimates, stds, seconds, cpu = np.empty(runs), np.empty(runs), np.empty(runs), np.empty(runs)
    for k in range(runs):
        start, start_cpu = time.perf_counter(), time.process_time()
        result = estimator.estimate(speeds, tau[k], LOAD_MEAN, LOAD_STD)
        seconds[k], cpu[k] = time.perf_counter() - start, time.process_time() - start_cpu
        estimates[k], stds[k] = result.estimate, result.std
    bound = 1.0 / marginal_fisher_wear(speeds, wear, LOAD_MEAN, LOAD_STD, n_draws=BOUND_DRAWS)
    variance = float(estimates.var(ddof=1))
    bias = float(estimates.mean() - wear)
    bias_tolerance = Z_999 * math.sqrt(2.0 * bound / runs)  # SE of the mean at the largest variance allowed
    row = {"design": name, "method": estimator.method if len(speeds) > 1 else "marginal (N=1)",
           "n_points": len(speeds), "speeds": [round(v, 2) for v in speeds], "wear": wear,
           "runs": runs, "mean": float(estimates.mean()), "bias": bias,
           "bias_z": bias / math.sqrt(variance / runs) if variance > 0 else math.nan,
           "bias_tolerance": bias_tolerance, "variance": variance, "bound": bound,
           "variance_ratio": variance / bound, "rmse": float(math.sqrt(np.mean((estimates - wear) ** 2))),
           "median_published_std": float(np.median(stds)),
           "fraction_at_zero": float(np.mean(estimates <= 1e-9)),
           "q95": float(np.quantile(estimates, 0.95)),
           "cpu_ms_per_call_mean": 1e3 * float(cpu.mean()),
           "ms_per_call_mean": 1e3 * float(seconds.mean()), "ms_per_call_max": 1e3 * float(seconds.max()),
           "estimates": estimates.tolist()}
    if len(speeds) >= 2:
        row["crlb_design"] = crlb_wear(speeds, 40.0, wear, LOAD_MEAN, LOAD_STD)
        row["crlb_mean_true"] = float(np.mean([crlb_wear(speeds, t, wear, LOAD_MEAN, LOAD_STD) for t in xi]))
    row["unbiased"] = abs(bias) <= bias_tolerance
    row["within_factor_2"] = 0.5 <= row["variance_ratio"] <= 2.0
    return row


def markdown_table(rows: list[dict]) -> str:
    lines = ["| design | method | speeds [rad/s] | ϖ | mean ϖ̂ | bias (tol.) | var | bound | var/bound | "
             "local CRLB at 40 °C | median published std | at 0 | q95 | wall ms/call (max) | CPU ms/call |",
             "|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|"]
    for r in rows:
        crlb = r.get("crlb_design")
        crlb_text = "—" if crlb is None else ("inf" if not math.isfinite(crlb) else f"{crlb:.3g}")
        ok_bias = "" if r["unbiased"] else " ✗"
        ok_var = "" if r["within_factor_2"] else " ✗"
        lines.append(
            f"| {r['design']} | {r['method']} | {', '.join(f'{v:g}' for v in r['speeds'])} | {r['wear']:g} | "
            f"{r['mean']:.2f} | "
            f"{r['bias']:+.2f} (±{r['bias_tolerance']:.2f}){ok_bias} | {r['variance']:.1f} | {r['bound']:.3g} | "
            f"{r['variance_ratio']:.2f}{ok_var} | {crlb_text} | {r['median_published_std']:.3g} | "
            f"{100 * r['fraction_at_zero']:.0f} % | {r['q95']:.1f} | "
            f"{r['ms_per_call_mean']:.1f} ({r['ms_per_call_max']:.1f}) | "
            f"{r['cpu_ms_per_call_mean']:.1f} |")
    return "\n".join(lines) + "\n"


def _label(row: dict) -> str:
    return row["design"].replace(" design", "") + ("" if row["n_points"] == 1 else f"\n{row['method']}")


def make_figures(rows: list[dict], out_dir: Path) -> list[str]:
    try:
        import matplotlib
        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
    except ImportError:
        print("matplotlib not installed: figures skipped", file=sys.stderr)
        return []
    written = []
    labels = list(dict.fromkeys(_label(r) for r in rows))
    fig, ax = plt.subplots(figsize=(11, 4.2))
    shown = [w for w in WEARS if w > 0]
    width = 0.8 / len(shown)
    for j, wear in enumerate(shown):
        sel = [next(r for r in rows if _label(r) == lab and r["wear"] == wear) for lab in labels]
        x = np.arange(len(labels)) + (j - (len(shown) - 1) / 2) * width
        ax.bar(x, [r["variance"] for r in sel], width, label=f"ϖ = {wear:g}: empirical variance")
        ax.scatter(x, [r["bound"] for r in sel], color="k", marker="_", s=150, zorder=3)
    ax.scatter([], [], color="k", marker="_", s=150, label="bound (marginal-likelihood CRLB)")
    ax.set_xticks(np.arange(len(labels)), labels, fontsize=7)
    ax.set_yscale("log")
    ax.set_ylabel("variance of ϖ̂")
    ax.legend(fontsize=7)
    ax.set_title("Empirical variance of the wear estimate vs the Cramér–Rao bound (ξ ~ U(30, 50))")
    fig.tight_layout()
    path = out_dir / "variance_vs_bound.png"
    fig.savefig(path, dpi=110)
    written.append(path.name)
    plt.close(fig)

    fig, axes = plt.subplots(1, 3, figsize=(12, 3.5))
    picks = (("N=2 design", "joint"), ("N=2 design", "marginal"), ("N=2 bad 82/133", "marginal"),
             ("N=4 design", "marginal"))
    for ax, wear in zip(axes, (0.0, 20.0, 35.0)):
        for design, method in picks:
            r = next(x for x in rows if x["design"] == design and x["method"] == method and x["wear"] == wear)
            ax.hist(r["estimates"], bins=np.linspace(0, 100, 51), histtype="step", label=f"{design}, {method}")
        ax.axvline(wear, color="k", lw=0.8)
        ax.set_xlabel("ϖ̂")
        ax.set_title(f"true ϖ = {wear:g}")
    axes[0].legend(fontsize=6)
    fig.tight_layout()
    path = out_dir / "histograms.png"
    fig.savefig(path, dpi=110)
    written.append(path.name)
    plt.close(fig)
    return written


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--runs", type=int, default=400, help="Monte Carlo cycles per configuration (≥ 200)")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--out-dir", type=Path, default=Path("docs/wear_estimation"))
    args = parser.parse_args(argv)
    args.out_dir.mkdir(parents=True, exist_ok=True)
    estimators = {m: WearEstimator(method=m) for m in ("joint", "marginal")}
    configs = [(f"N={n} design", design_speeds(n).speeds) for n in (1, 2, 3, 4)]
    configs.append(("N=2 bad 82/133", BAD_SPEEDS))
    rows = []
    for i, (name, speeds) in enumerate(configs):
        for method in (("marginal",) if len(speeds) == 1 else ("joint", "marginal")):
            for j, wear in enumerate(WEARS):
                row = study_config(estimators[method], name, speeds, wear, args.runs,
                                   seed=args.seed + 1000 * i + j)
                rows.append(row)
                print(f"{name:16s} {method:8s} ϖ={wear:4.0f}: mean {row['mean']:6.2f}  var {row['variance']:7.1f}  "
                      f"bound {row['bound']:7.1f}  ratio {row['variance_ratio']:5.2f}  "
                      f"{row['ms_per_call_mean']:.1f} ms/call", flush=True)
    table = markdown_table(rows)
    (args.out_dir / "mc_table.md").write_text(table, encoding="utf-8")
    summary = [{k: v for k, v in r.items() if k != "estimates"} for r in rows]
    (args.out_dir / "mc_results.json").write_text(json.dumps({"runs": args.runs, "seed": args.seed,
                                                              "rows": summary}, indent=1), encoding="utf-8")
    figures = make_figures(rows, args.out_dir)
    print(table)
    print("figures:", ", ".join(figures) or "none")
    return 0


if __name__ == "__main__":
    sys.exit(main())
