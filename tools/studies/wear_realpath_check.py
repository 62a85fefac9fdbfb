#!/usr/bin/env python3
"""Wear estimate through the real path: design → simulated controller → CAN log → agent replay.

For N = 2, 3, 4 designed speeds: ``edge-monitor design --points N --json``, ``sim-controller record
--joints 1 --cycles C --speeds-from design.json --temperature-range 40:40 --wear-ramp all:0:1:35:35``,
``edge-monitor replay`` with an agent config whose ``[segmentation] speeds`` are the designed speeds and
whose per-joint model learning is off (the joint is the base table, worn from its first cycle; a second
row keeps the learning on, which learns the wear as part of the joint's temperature relation), then
bias, variance (against the design CRLB) and the mean reported std of ``wear.estimate`` over cycles
≥ 2: all of them, then separately those estimated with the motor-temperature prior on ξ (the steady
state) and those before it (the first ``wear.prior_cycles`` cycles, ξ flat over the site range). With
``--also-default-config`` the replay is repeated with the agent's default config (the 12 default speed
levels and the learning on), which is what the issue ran; the table's "data per cycle" says how many
designed plateaus the default levels kept (once only one; docs/WEAR_ESTIMATION.md §4.1).

Usage: .venv/bin/python tools/studies/wear_realpath_check.py [--cycles 150] [--points 2 3 4]
       [--also-default-config] [--work-dir DIR] [--out docs/wear_estimation/realpath.md]
"""

from __future__ import annotations

import argparse
import json
import math
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np

BIN = Path(sys.executable).parent
TRUE_WEAR = 35.0
#: The joint is the base table and worn from its first cycle: nothing for the per-joint learning to learn,
#: and what it would learn (a temperature relation fitted with wear 0) is wrong (docs/WEAR_ESTIMATION.md §4.1).
MODEL_OFF = "[model]\nenabled = false\n"


def run(cmd: list[str], stdout: Path | None = None) -> None:
    """Run one command of the pipeline; its output goes to ``stdout`` (a file) or is discarded."""
    with open(stdout, "w", encoding="utf-8") if stdout else open("/dev/null", "w") as out:
        subprocess.run(cmd, check=True, stdout=out, stderr=subprocess.DEVNULL)


#: Subsets of a replay's cycles ≥ 2 the statistics are given for: all of them, those whose estimate used
#: the motor-temperature prior on ξ, and those before it (the relation still being learned: ξ flat over
#: the site range, a wider posterior; docs/WEAR_ESTIMATION.md §4.1).
SUBSETS = {"all": lambda r: True,
           "motor-temperature prior": lambda r: r["wear"].get("temperature_prior") is not None,
           "flat ξ (relation being learned)": lambda r: r["wear"].get("temperature_prior") is None}


def summarise(symptoms: Path, design: dict, label: str) -> list[dict]:
    """Statistics of ``wear`` over cycles ≥ 2 of a replay's symptom records, one row per non-empty subset."""
    records = [json.loads(line) for line in symptoms.read_text(encoding="utf-8").splitlines() if line.strip()]
    valid = [r for r in records if r["cycle"] >= 2 and r["wear"]["estimate"] is not None]
    rows = []
    for subset, keep in SUBSETS.items():
        used = [r for r in valid if keep(r)]
        if len(used) >= 2:
            rows.append({"label": label, "cycles": subset, **_statistics(used, design)})
    return rows


def _statistics(used: list[dict], design: dict) -> dict:
    est = np.array([r["wear"]["estimate"] for r in used])
    std = np.array([r["wear"]["std"] for r in used])
    upper = np.array([r["wear"].get("upper_95") if r["wear"].get("upper_95") is not None else math.nan
                      for r in used])
    n_data = sorted({len(r["friction"]["speeds"]) for r in used})
    spread = float(est.std(ddof=1))
    crlb = design["wear_crlb"]
    return {"n_points_design": len(design["speeds"]), "data_per_cycle": n_data,
            "cycles_used": int(est.size), "mean": float(est.mean()), "bias": float(est.mean() - TRUE_WEAR),
            "bias_se": spread / math.sqrt(est.size), "variance": spread ** 2, "design_crlb": crlb,
            "variance_ratio": spread ** 2 / crlb, "mean_reported_std": float(std.mean()),
            "mean_reported_variance": float(np.mean(std ** 2)), "observed_sd": spread,
            "std_ratio": float(std.mean()) / spread,
            "coverage_upper_95": float(np.mean(TRUE_WEAR <= upper)) if np.all(np.isfinite(upper)) else None,
            "identifiable": float(np.mean([bool(r["wear"].get("identifiable")) for r in used]))}


def check(points: int, cycles: int, work: Path, also_default: bool) -> list[dict]:
    design_json = work / f"design{points}.json"
    run([str(BIN / "edge-monitor"), "design", "--points", str(points), "--json"], stdout=design_json)
    design = json.loads(design_json.read_text(encoding="utf-8"))
    log_file, truth = work / f"x{points}.blf", work / f"t{points}.jsonl"
    run([str(BIN / "sim-controller"), "record", "--joints", "1", "--cycles", str(cycles), "--speeds-from",
         str(design_json), "--temperature-range", "40:40", "--wear-ramp", "all:0:1:35:35",
         "--out", str(log_file), "--truth", str(truth)])
    speeds = "[segmentation]\nspeeds = [" + ", ".join(repr(v) for v in design["speeds"]) + "]\n"
    config, learning = work / f"agent{points}.toml", work / f"agent{points}_learning.toml"
    config.write_text(speeds + MODEL_OFF, encoding="utf-8")
    learning.write_text(speeds, encoding="utf-8")
    rows = []
    variants = [("designed speeds, base table", ["--config", str(config)]),
                ("designed speeds, per-joint learning", ["--config", str(learning)])]
    if also_default:
        variants.append(("default config (12 levels)", []))
    for k, (label, extra) in enumerate(variants):
        symptoms = work / f"s{points}_{k}.jsonl"
        symptoms.unlink(missing_ok=True)
        run([str(BIN / "edge-monitor"), "replay", str(log_file), *extra, "--jsonl", str(symptoms)])
        rows += summarise(symptoms, design, label)
    return rows


def markdown(rows: list[dict], cycles: int) -> str:
    lines = [f"Real path, {cycles} cycles at ξ = 40 °C, ϖ = 35 (statistics over cycles ≥ 2):", "",
             "| design N | agent config | cycles | data per cycle | n | bias ± SE | variance | design CRLB | "
             "var/CRLB | mean reported std / observed sd | coverage of upper_95 | identifiable |",
             "|---|---|---|---|---|---|---|---|---|---|---|---|"]
    for r in rows:
        cov = "—" if r["coverage_upper_95"] is None else f"{r['coverage_upper_95']:.3f}"
        lines.append(f"| {r['n_points_design']} | {r['label']} | {r['cycles']} | {r['data_per_cycle']} | "
                     f"{r['cycles_used']} | "
                     f"{r['bias']:+.2f} ± {r['bias_se']:.2f} | {r['variance']:.1f} | {r['design_crlb']:.2f} | "
                     f"{r['variance_ratio']:.2f} | {r['mean_reported_std']:.2f} / {r['observed_sd']:.2f} = "
                     f"{r['std_ratio']:.2f} | {cov} | {100 * r['identifiable']:.0f} % |")
    return "\n".join(lines) + "\n"


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--cycles", type=int, default=150)
    parser.add_argument("--points", type=int, nargs="+", default=[2, 3, 4])
    parser.add_argument("--also-default-config", action="store_true")
    parser.add_argument("--work-dir", type=Path, help="keep the logs here (default: a temporary directory)")
    parser.add_argument("--out", type=Path, help="write the markdown table (and a .json next to it) here")
    args = parser.parse_args(argv)
    with tempfile.TemporaryDirectory() as tmp:
        work = args.work_dir or Path(tmp)
        work.mkdir(parents=True, exist_ok=True)
        rows = []
        for points in args.points:
            rows += check(points, args.cycles, work, args.also_default_config)
            print(f"N = {points} done", file=sys.stderr, flush=True)
    text = markdown(rows, args.cycles)
    print(text)
    if args.out:
        args.out.write_text(text, encoding="utf-8")
        args.out.with_suffix(".json").write_text(json.dumps({"cycles": args.cycles, "rows": rows}, indent=1),
                                                 encoding="utf-8")
    return 0


if __name__ == "__main__":
    sys.exit(main())
