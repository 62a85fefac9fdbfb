#!/usr/bin/env python3
"""The prognosis validated like a prognostics result (docs/PROGNOSIS.md): the agent's prognosis replayed
on the recorded inputs of simulated wearing and healthy joints (``tools/studies/prognosis_series.py``
computes and keeps them), per wear law the coverage of the 80 % band, α–λ accuracy (α = 0.2, λ = 0.5),
relative accuracy and prognostic horizon of the shipped model next to the alternatives and the naive
baseline; per healthy joint the share of cycles "beyond the horizon" and the early warnings.

Usage: ``python tools/studies/prognosis_study.py [--wear 4801-4806] [--healthy 4901] [--models
drifting_rate,wiener,accelerating,line] [--set prognosis.KEY=VALUE ...] [--json PATH] [--jobs 2]``.
A model's settings other than the shipped ones: ``--set MODEL.KEY=VALUE`` (e.g. ``wiener.level_diffusion=0.05``).
"""

from __future__ import annotations

import os

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import argparse  # noqa: E402
import dataclasses  # noqa: E402
import json  # noqa: E402
import logging  # noqa: E402
import sys  # noqa: E402
import time  # noqa: E402
from concurrent.futures import ProcessPoolExecutor  # noqa: E402
from pathlib import Path  # noqa: E402
from typing import Any  # noqa: E402

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT))

from edge_monitor.features.prognosis import PrognosisConfig  # noqa: E402
from studies.prognosis_metrics import (  # noqa: E402
    ALPHA,
    cell,
    law_table,
    oracle_line,
    replay,
    score_healthy,
    score_joint,
)
from studies.prognosis_series import add_fleet_arguments, fleets, rows  # noqa: E402

#: Each model at the settings the study compares (the shipped model at the agent's defaults).
MODELS = ("drifting_rate", "multi_rate", "wiener", "accelerating", "line")
#: The alternatives at the settings that did best on the tuning seeds 4701-4702 (docs/PROGNOSIS.md).
STUDY_SETTINGS: dict[str, dict[str, Any]] = {
    "drifting_rate": {},
    "multi_rate": {"forgetting": 0.97},
    "wiener": {"level_diffusion": 0.2},
    "accelerating": {"acceleration_drift": 1e-9},
    "line": {"window": 100},
}


def model_config(model: str, overrides: dict[str, dict[str, Any]]) -> PrognosisConfig:
    settings = {**STUDY_SETTINGS.get(model, {}), **overrides.get(model, {}), "model": model}
    return dataclasses.replace(PrognosisConfig(), **settings)


def evaluate(config: PrognosisConfig, wearing: list[dict[str, Any]], healthy: list[dict[str, Any]]) -> dict[str, Any]:
    """Per-law table and healthy summary of one model over the kept robots."""
    scores = []
    for robot in wearing:
        for joint, joint_rows in rows(robot).items():
            scores.append(score_joint(robot["laws"][joint]["law"], joint_rows, config))
    healthy_scores = [score_healthy(replay(joint_rows, config)) for robot in healthy
                      for joint_rows in rows(robot).values()]
    cycles = sum(h.cycles for h in healthy_scores)
    return {"laws": law_table(scores), "healthy": {
        "joints": len(healthy_scores), "cycles": cycles,
        "beyond_share": sum(h.beyond for h in healthy_scores) / cycles if cycles else None,
        "worst_joint_beyond_share": min((h.beyond_share for h in healthy_scores if h.beyond_share is not None),
                                        default=None),
        "warnings": sum(h.warnings for h in healthy_scores)},
        "settings": dataclasses.asdict(config)}


def oracle(wearing: list[dict[str, Any]]) -> dict[str, dict[str, Any]]:
    """Per straight law: the joints whose oracle line (the law's shape and start known, fitted to the
    estimates) is within ±α of the true remaining life at λ, and the median relative error."""
    out: dict[str, list[float]] = {}
    for robot in wearing:
        for joint, joint_rows in rows(robot).items():
            law = robot["laws"][joint]
            fit = oracle_line(law["law"], law["events"][-1]["start"], joint_rows)
            if fit is not None:
                out.setdefault(law["law"], []).append(fit[2])
    return {law: {"joints": len(errors), "within_alpha": sum(e <= ALPHA for e in errors),
                  "median_error": float(sorted(errors)[len(errors) // 2])} for law, errors in out.items()}


def print_table(results: dict[str, dict[str, Any]]) -> None:
    print(f"{'model':<14} {'law':<12} {'joints':>6} {'alarmed':>7} {'wear@alarm':>10} {'coverage':>8} "
          f"{'α–λ':>6} {'RA':>6} {'PH':>6}")
    for model, result in results.items():
        for law, row in result["laws"].items():
            print(f"{model:<14} {law:<12} {row['joints']:>6} {row['alarmed']:>7} {cell(row['alarm_wear'], '.1f'):>10} "
                  f"{cell(row['coverage'], '.2f'):>8} {cell(row['alpha_lambda'], '.2f'):>6} "
                  f"{cell(row['relative_accuracy'], '.2f'):>6} {cell(row['horizon_share'], '.2f'):>6}")
        h = result["healthy"]
        print(f"{model:<14} {'healthy':<12} {h['joints']:>6} joints, {h['cycles']} cycles: beyond the horizon "
              f"{cell(h['beyond_share'], '.4f')} (worst joint {cell(h['worst_joint_beyond_share'], '.4f')}), "
              f"{h['warnings']} early warning(s)")


def parse_set(items: list[str]) -> dict[str, dict[str, Any]]:
    out: dict[str, dict[str, Any]] = {}
    for item in items:
        key, _, value = item.partition("=")
        model, _, name = key.partition(".")
        parsed = json.loads(value)
        out.setdefault(model, {})[name] = tuple(parsed) if isinstance(parsed, list) else parsed
    return out


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    add_fleet_arguments(parser)
    parser.add_argument("--models", default=",".join(MODELS))
    parser.add_argument("--set", action="append", default=[], metavar="MODEL.KEY=VALUE")
    parser.add_argument("--json", type=Path, help="write every number here")
    args = parser.parse_args(argv)
    logging.basicConfig(level=logging.WARNING, format="%(asctime)s %(name)s %(message)s")
    logging.getLogger("edge_monitor").setLevel(logging.ERROR)
    started = time.monotonic()
    wearing, healthy = fleets(args)
    overrides = parse_set(args.set)
    models = [m for m in args.models.split(",") if m]
    configs = [model_config(m, overrides) for m in models]
    with ProcessPoolExecutor(max(1, min(args.jobs, len(configs)))) as pool:
        results = dict(zip(models, pool.map(evaluate, configs, [wearing] * len(configs), [healthy] * len(configs))))
    print_table(results)
    bound = oracle(wearing)
    for law, row in bound.items():
        print(f"oracle line    {law:<12} {row['joints']:>6} joints: α–λ {row['within_alpha']}/{row['joints']}, "
              f"median relative error {row['median_error']:.2f} (the law's shape and start known)")
    if args.json:
        args.json.write_text(json.dumps({"models": results, "oracle_line": bound}, indent=1, default=str))
    print(f"{sum(len(r['joints']) for r in wearing)} wearing and {sum(len(r['joints']) for r in healthy)} healthy "
          f"joints, {time.monotonic() - started:.0f} s")
    return 0


if __name__ == "__main__":
    sys.exit(main())
