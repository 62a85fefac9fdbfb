#!/usr/bin/env python3
"""Monte Carlo quality study of the per-cycle wear estimate (docs/WEAR_ESTIMATION.md §4).

Data are generated as ``sim_controller`` generates them (checked against its truth sidecar, see the
doc): per cycle |τl| ~ U(0.3, 0.7), the controller's estimate μl = τl + N(0, σl²) with σl = 0.1,
a per-cycle, per-level model error δk ~ N(0, σm²) with σm = 5.7e-3, and the plateau-mean error of
the friction extraction N(0, 7e-5²) (its stderr, passed to the estimator). The lubricant temperature
is FIXED per configuration (the complaint is about a joint held at 40 °C, and the thermal model
changes ξ slowly), so every row is the estimator's behaviour at one (ξ, ϖ).

Parts (all seeded; one command reproduces every number and figure):

1. design point ξ = 40 °C, ϖ = 35, design speeds N = 2, 3, 4 (``design_speeds``), both methods,
   ``4·runs`` cycles: bias, variance against the design CRLB [F⁻¹]₂₂, reported std against the
   observed spread, coverage of ``upper_95``, CPU time per call;
2. temperature sweep ξ = 30 … 50 °C (site range 30 … 50), ϖ ∈ {0, 5, 10, 20, 35, 50}, design speeds
   N = 2, 3, 4, method "marginal";
3. the 12 default speeds with the site range 30 … 80 °C at ξ = 30 … 60 °C, ϖ ∈ {0, 5, 10, 35}.

Writes ``mc_results.json``, ``mc_tables.md`` and figures into ``--out-dir``.

Usage: .venv/bin/python tools/studies/mc_wear_study.py [--runs 400] [--seed 0] [--out-dir docs/wear_estimation]
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import time
from pathlib import Path

import numpy as np

from edge_monitor.features.wear_estimation import WearEstimator
from edge_monitor.features.wear_information import crlb_wear
from edge_monitor.offline.experiment_design import design_speeds
from joint_model.friction import FRICTION_NOISE_STD, friction_magnitude

DEFAULT_SPEEDS = [2.1, 8.7, 15.3, 21.9, 28.5, 35.1, 41.7, 82.2, 133.5, 184.7, 236.2, 287.1]
LOAD_RANGE = (0.3, 0.7)          # sim_controller: |τl| ~ U(load_range)
LOAD_STD = 0.1                   # σl of the controller's load estimate
MODEL_ERROR_STD = 5.7e-3         # σm of the per-cycle, per-level model error (= FRICTION_NOISE_STD)
EXTRACTION_STDERR = 7e-5         # stderr of a plateau-mean friction datum measured on the real path
DESIGN_POINT = (40.0, 35.0)
SWEEP_TEMPERATURES = (30.0, 32.5, 35.0, 37.5, 40.0, 42.5, 45.0, 47.5, 50.0)
SWEEP_WEARS = (0.0, 5.0, 10.0, 20.0, 35.0, 50.0)
DEFAULT_TEMPERATURES = (30.0, 40.0, 50.0, 60.0)
DEFAULT_WEARS = (0.0, 5.0, 10.0, 35.0)
COVERAGE_LEVEL = 0.95


def simulate(speeds: list[float], temperature: float, wear: float, runs: int,
             rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """Friction data (runs × N) and load estimates μl of ``runs`` cycles, as sim_controller makes them."""
    v = np.asarray(speeds, dtype=float)
    load = rng.uniform(*LOAD_RANGE, runs)
    load_estimate = load + rng.normal(0.0, LOAD_STD, runs)
    tau = (friction_magnitude(v[None, :], load[:, None], temperature, wear)
           + rng.normal(0.0, MODEL_ERROR_STD, (runs, v.size))
           + rng.normal(0.0, EXTRACTION_STDERR, (runs, v.size)))
    return tau, load_estimate


def run_config(estimator: WearEstimator, speeds: list[float], temperature: float, wear: float, runs: int,
               seed: int) -> dict:
    """Estimates of ``runs`` cycles at one (speeds, ξ, ϖ) and their summary statistics."""
    tau, load_estimate = simulate(speeds, temperature, wear, runs, np.random.default_rng(seed))
    stderr = [EXTRACTION_STDERR] * len(speeds)
    est, std, upper, ident, cpu = (np.empty(runs) for _ in range(5))
    for k in range(runs):
        c0 = time.process_time()
        r = estimator.estimate(speeds, tau[k], load_estimate[k], LOAD_STD, friction_stderr=stderr)
        cpu[k] = time.process_time() - c0
        est[k], std[k], upper[k], ident[k] = r.estimate, r.std, r.upper_95, r.identifiable
    spread = float(est.std(ddof=1))
    reported = float(math.sqrt(np.mean(std ** 2)))       # RMS of the published std
    crlb = crlb_wear(speeds, temperature, max(wear, 1e-9), 0.5, LOAD_STD,
                     friction_stderr=stderr) if len(speeds) > 1 else math.inf
    return {"n_points": len(speeds), "method": estimator.method if len(speeds) > 1 else "marginal",
            "temperature": temperature, "wear": wear, "runs": runs, "seed": seed,
            "mean": float(est.mean()), "bias": float(est.mean() - wear), "bias_se": spread / math.sqrt(runs),
            "variance": spread ** 2, "sd": spread, "reported_std": reported, "std_ratio": reported / spread,
            "crlb_local": crlb, "variance_ratio": spread ** 2 / crlb if math.isfinite(crlb) else None,
            "coverage": float(np.mean(wear <= upper)), "upper_median": float(np.median(upper)),
            "identifiable": float(np.mean(ident)), "q95": float(np.quantile(est, 0.95)),
            "cpu_ms_mean": 1e3 * float(cpu.mean()), "cpu_ms_p99": 1e3 * float(np.quantile(cpu, 0.99))}


def _fmt(x: float | None, spec: str = ".2f") -> str:
    return "—" if x is None or not math.isfinite(x) else format(x, spec)


def table(rows: list[dict], with_method: bool = False) -> str:
    head = ("| N | " + ("method | " if with_method else "") + "ξ °C | ϖ | bias ± SE | variance | local CRLB | "
            "var/CRLB | reported std / spread | coverage of upper_95 | median upper_95 | identifiable | CPU ms |")
    lines = [head, "|" + "---|" * (head.count("|") - 1)]
    for r in rows:
        lines.append(
            f"| {r['n_points']} | " + (f"{r['method']} | " if with_method else "")
            + f"{r['temperature']:g} | {r['wear']:g} | {r['bias']:+.2f} ± {r['bias_se']:.2f} | "
            f"{r['variance']:.1f} | {_fmt(r['crlb_local'], '.3g')} | {_fmt(r['variance_ratio'])} | "
            f"{r['reported_std']:.2f} / {r['sd']:.2f} = {r['std_ratio']:.2f} | {r['coverage']:.3f} | "
            f"{r['upper_median']:.1f} | {100 * r['identifiable']:.0f} % | {r['cpu_ms_mean']:.2f} |")
    return "\n".join(lines) + "\n"


def make_figures(sweep: list[dict], default: list[dict], out_dir: Path) -> list[str]:
    try:
        import matplotlib
        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
    except ImportError:
        print("matplotlib not installed: figures skipped", file=sys.stderr)
        return []
    written = []
    fig, axes = plt.subplots(1, 3, figsize=(13, 3.8))
    for n, color in zip((2, 3, 4), ("tab:blue", "tab:orange", "tab:green")):
        for wear, style in ((35.0, "-"), (20.0, ":")):
            rows = [r for r in sweep if r["n_points"] == n and r["wear"] == wear]
            t = [r["temperature"] for r in rows]
            label = f"N = {n}, ϖ = {wear:g}"
            axes[0].plot(t, [r["bias"] for r in rows], style, color=color, marker="o", ms=3, label=label)
            axes[1].plot(t, [r["sd"] for r in rows], style, color=color, marker="o", ms=3, label=label)
            axes[1].plot(t, [r["reported_std"] for r in rows], style, color=color, alpha=0.4)
            axes[2].plot(t, [r["coverage"] for r in rows], style, color=color, marker="o", ms=3, label=label)
    axes[0].axhspan(-2, 2, color="0.9")
    axes[0].set_ylabel("bias of ϖ̂")
    axes[1].set_ylabel("spread of ϖ̂ (marker) / reported std (faint)")
    axes[1].set_ylim(0, None)
    axes[2].axhline(COVERAGE_LEVEL, color="k", lw=0.8)
    axes[2].set_ylabel("P(ϖ ≤ upper_95)")
    for ax in axes:
        ax.set_xlabel("lubricant temperature ξ [°C]")
    axes[0].legend(fontsize=7)
    fig.suptitle("Design speeds, method 'marginal', site range 30–50 °C: bias, spread and bound vs temperature")
    fig.tight_layout()
    fig.savefig(out_dir / "bias_variance_vs_temperature.png", dpi=110)
    written.append("bias_variance_vs_temperature.png")
    plt.close(fig)

    fig, axes = plt.subplots(1, 3, figsize=(13, 3.8))
    for wear, color in zip(DEFAULT_WEARS, ("k", "tab:purple", "tab:red", "tab:blue")):
        rows = [r for r in default if r["wear"] == wear]
        t = [r["temperature"] for r in rows]
        axes[0].plot(t, [r["mean"] for r in rows], color=color, marker="o", label=f"ϖ = {wear:g}")
        axes[0].axhline(wear, color=color, lw=0.6, ls=":")
        axes[1].plot(t, [r["sd"] for r in rows], color=color, marker="o", label=f"ϖ = {wear:g}")
        axes[1].plot(t, [r["reported_std"] for r in rows], color=color, alpha=0.4)
        axes[2].plot(t, [r["upper_median"] for r in rows], color=color, marker="o", label=f"ϖ = {wear:g}")
    axes[0].set_ylabel("mean ϖ̂ (dotted: truth)")
    axes[1].set_ylabel("spread of ϖ̂ (marker) / reported std (faint)")
    axes[2].set_ylabel("median upper_95")
    for ax in axes:
        ax.set_xlabel("lubricant temperature ξ [°C]")
    axes[0].legend(fontsize=7)
    fig.suptitle("12 default speeds, site range 30–80 °C")
    fig.tight_layout()
    fig.savefig(out_dir / "default_speeds.png", dpi=110)
    written.append("default_speeds.png")
    plt.close(fig)
    return written


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--runs", type=int, default=400, help="cycles per configuration (design point: 4×)")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--out-dir", type=Path, default=Path("docs/wear_estimation"))
    args = parser.parse_args(argv)
    if args.runs < 50:
        parser.error("--runs: need ≥ 50")
    args.out_dir.mkdir(parents=True, exist_ok=True)
    designs = {n: design_speeds(n).speeds for n in (2, 3, 4)}
    estimators = {m: WearEstimator(method=m) for m in ("marginal", "joint")}
    seed = args.seed

    design_rows = []
    for n, speeds in designs.items():
        for method, est in estimators.items():
            design_rows.append(run_config(est, speeds, *DESIGN_POINT, 4 * args.runs, seed + 10 * n))
            r = design_rows[-1]
            print(f"design N={n} {method:8s}: bias {r['bias']:+.2f} var {r['variance']:.1f} "
                  f"(CRLB {r['crlb_local']:.1f}, ratio {r['variance_ratio']:.2f}) std ratio {r['std_ratio']:.2f} "
                  f"coverage {r['coverage']:.3f} {r['cpu_ms_mean']:.2f} ms", flush=True)

    sweep_rows = []
    for n, speeds in designs.items():
        for j, wear in enumerate(SWEEP_WEARS):
            for i, temperature in enumerate(SWEEP_TEMPERATURES):
                sweep_rows.append(run_config(estimators["marginal"], speeds, temperature, wear, args.runs,
                                             seed + 1000 * n + 100 * j + i))
        print(f"sweep N={n} done", flush=True)

    wide = WearEstimator(method="marginal", temperature_range=(30.0, 80.0))
    default_rows = []
    for j, wear in enumerate(DEFAULT_WEARS):
        for i, temperature in enumerate(DEFAULT_TEMPERATURES):
            default_rows.append(run_config(wide, DEFAULT_SPEEDS, temperature, wear, args.runs,
                                           seed + 50000 + 100 * j + i))
    print("default speeds done", flush=True)

    tables = ("## Design point (ξ = 40 °C, ϖ = 35), " f"{4 * args.runs} cycles per row\n\n"
              + table(design_rows, with_method=True)
              + f"\n## Temperature sweep, design speeds, method marginal, site range 30–50 °C, {args.runs} cycles\n\n"
              + table(sweep_rows)
              + f"\n## 12 default speeds, site range 30–80 °C, method marginal, {args.runs} cycles\n\n"
              + table(default_rows))
    (args.out_dir / "mc_tables.md").write_text(tables, encoding="utf-8")
    results = {"runs": args.runs, "seed": args.seed, "design_speeds": designs,
               "data_model": {"load_range": LOAD_RANGE, "load_std": LOAD_STD, "model_error_std": MODEL_ERROR_STD,
                              "extraction_stderr": EXTRACTION_STDERR, "noise_std_estimator": FRICTION_NOISE_STD},
               "design_point": design_rows, "sweep": sweep_rows, "default_speeds": default_rows}
    (args.out_dir / "mc_results.json").write_text(json.dumps(results, indent=1), encoding="utf-8")
    figures = make_figures(sweep_rows, default_rows, args.out_dir)
    print(tables)
    print("figures:", ", ".join(figures) or "none")
    return 0


if __name__ == "__main__":
    sys.exit(main())
