#!/usr/bin/env python3
"""Where the prognosis's α–λ error comes from: the agent's trend model on the same wearing joints fed seven
inputs, from the agent's estimates to the true wear (:data:`studies.prognosis_error_budget.VARIANTS`).

Usage: ``python tools/studies/prognosis_error_budget.py --wear 4801-4806 [--repeats 5] [--set forgetting=0.99]
[--jobs 2] [--keep-series] [--json PATH]``. The first run computes the ``known_model`` inputs (≈ 3 min per
robot alone) next to the ``wear`` ones that ``tools/studies/prognosis_series.py`` keeps.
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

import numpy as np  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))

from edge_monitor.features.prognosis import PrognosisConfig  # noqa: E402
from joint_model import CRITICAL_WEAR, FrictionParams  # noqa: E402
from studies.prognosis_error_budget import (  # noqa: E402
    SHUFFLE_BIN,
    STRAIGHT_LAWS,
    VARIANTS,
    bias_in_band,
    joint_summary,
    nominal_equivalent,
    posterior_mean_rows,
    shuffled_rows,
    synthetic_rows,
)
from studies.prognosis_fleet import known_model_settings, robot_config, robot_laws  # noqa: E402
from studies.prognosis_metrics import WearScore, cell, law_table, score_joint  # noqa: E402
from studies.prognosis_series import fleet, rows  # noqa: E402
from studies.settings import parse_seeds, parse_set  # noqa: E402


def score_robot(wear_robot: dict[str, Any], known_robot: dict[str, Any], config: PrognosisConfig,
                repeats: int) -> list[tuple[str, dict[str, list[WearScore]], dict[str, Any]]]:
    """Per joint of one robot: (law, {variant: its WearScores — one per noise draw for the synthetic
    inputs, one otherwise}, per-joint summary)."""
    seed = wear_robot["seed"]
    settings = known_model_settings(robot_config(seed, robot_laws(seed)))
    agent_rows, known_rows = rows(wear_robot), rows(known_robot)
    out = []
    for joint, joint_rows in agent_rows.items():
        law = wear_robot["laws"][joint]["law"]
        reading = nominal_equivalent(FrictionParams.from_mapping(settings["joint"][str(joint)]["friction"]))
        inputs = {"agent": [joint_rows], "posterior_mean": [posterior_mean_rows(joint_rows)],
                  "known_model": [known_rows[joint]],
                  "shuffled_in_bins": [shuffled_rows(joint_rows, g, SHUFFLE_BIN)
                                       for g in _draws(seed, joint, "shuffled_in_bins", repeats)],
                  "shuffled": [shuffled_rows(joint_rows, g, None) for g in _draws(seed, joint, "shuffled", repeats)],
                  "wear_coefficients": [synthetic_rows(joint_rows, reading, g)
                                        for g in _draws(seed, joint, "wear_coefficients", repeats)],
                  "truth": [synthetic_rows(joint_rows, None, g) for g in _draws(seed, joint, "truth", repeats)]}
        scores = {variant: [score_joint(law, r, config) for r in inputs[variant]] for variant in VARIANTS}
        biases = {"agent": bias_in_band(joint_rows), "posterior_mean": bias_in_band(inputs["posterior_mean"][0]),
                  "known_model": bias_in_band(known_rows[joint])}
        at_critical = float(np.interp(CRITICAL_WEAR, *reading))
        out.append((law, scores, joint_summary(law, joint, seed, scores, biases, at_critical)))
    return out


def _draws(seed: int, joint: int, variant: str, repeats: int) -> list[np.random.Generator]:
    """The noise draws of one synthetic input of one joint: its own seeds, independent of the others'."""
    return [np.random.default_rng([seed, joint, 48, k, VARIANTS.index(variant)]) for k in range(repeats)]


def mean_table(per_draw: list[list[WearScore]]) -> dict[str, dict[str, float | None]]:
    """:func:`law_table` of each draw (``per_draw[j][k]``: joint j, draw k; one draw for the real inputs),
    α–λ and coverage averaged over the draws."""
    tables = []
    for k in range(len(per_draw[0])):
        table = law_table([scores[k] for scores in per_draw])
        straight = [scores[k] for scores in per_draw if scores[k].law in STRAIGHT_LAWS]
        if straight:
            table["straight"] = law_table(straight)["all"]
        tables.append(table)
    out: dict[str, dict[str, float | None]] = {}
    for law in tables[0]:
        out[law] = {"joints": tables[0][law]["joints"]}
        for key in ("alpha_lambda", "coverage", "relative_accuracy"):
            values = [float(v) for t in tables if (v := t[law][key]) is not None]
            out[law][key] = float(np.mean(values)) if values else None
    return out


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--wear", default="4801-4806", help="seeds of wearing robots (default 4801-4806)")
    parser.add_argument("--jobs", type=int, default=2, help="processes (default 2)")
    parser.add_argument("--keep-series", action="store_true", help="use inputs kept by other code")
    parser.add_argument("--repeats", type=int, default=5, help="noise draws of the synthetic inputs (default 5)")
    parser.add_argument("--set", action="append", default=[], metavar="KEY=VALUE", type=parse_set,
                        help="a [prognosis] setting other than the shipped one, the value as JSON (e.g. forgetting=0.99)")
    parser.add_argument("--json", type=Path, help="write every number here")
    args = parser.parse_args(argv)
    logging.basicConfig(level=logging.INFO, format="%(asctime)s %(name)s %(message)s")
    logging.getLogger("edge_monitor").setLevel(logging.ERROR)
    started = time.monotonic()
    seeds = parse_seeds(args.wear)
    wearing = fleet("wear", seeds, args.jobs, args.keep_series)
    known = fleet("known_model", seeds, args.jobs, args.keep_series)
    changes: dict[str, Any] = {key: tuple(v) if isinstance(v, list) else v for key, v in args.set}
    config = dataclasses.replace(PrognosisConfig(), **changes)
    with ProcessPoolExecutor(max(1, min(args.jobs, len(seeds)))) as pool:
        per_robot = list(pool.map(score_robot, wearing, known, [config] * len(seeds), [args.repeats] * len(seeds)))
    joints = [j for robot in per_robot for j in robot]
    tables = {v: mean_table([scores[v] for _, scores, _ in joints]) for v in VARIANTS}
    print(f"{'law':<12} {'joints':>6} " + " ".join(f"{v + ' α–λ / cov':>27}" for v in VARIANTS))
    for law in tables["agent"]:
        cells = [f"{cell(tables[v][law]['alpha_lambda'], '.2f')} / {cell(tables[v][law]['coverage'], '.2f')}"
                 for v in VARIANTS]
        print(f"{law:<12} {tables['agent'][law]['joints']:>6} " + " ".join(f"{c:>27}" for c in cells))
    summaries = [s for _, _, s in joints]
    print("\nper joint: bias (estimate − true wear, true wear 10–30) and the nominal coefficients' reading of 35")
    for s in summaries:
        passed = " ".join(f"{s['alpha_lambda'][v]:.1f}" for v in VARIANTS)
        print(f"  seed {s['seed']} joint {s['joint']} {s['law']:<12} α–λ {passed}  bias agent "
              f"{cell(s['bias']['agent'], '+.1f')}, posterior mean {cell(s['bias']['posterior_mean'], '+.1f')}, "
              f"known model {cell(s['bias']['known_model'], '+.1f')}; "
              f"35 reads {s['nominal_reading_at_critical']:.1f}")
    for variant in ("agent", "posterior_mean", "known_model"):
        b = np.array([s["bias"][variant] for s in summaries if s["bias"][variant] is not None])
        print(f"{variant}: bias over {b.size} joints: mean {b.mean():+.2f}, sd {b.std(ddof=1):.2f}, "
              f"|bias| ≤ 2 on {int(np.sum(np.abs(b) <= 2))}")
    if args.json:
        args.json.write_text(json.dumps({"settings": dataclasses.asdict(config), "repeats": args.repeats,
                                         "tables": tables, "joints": summaries}, indent=1, default=str))
    print(f"{len(joints)} wearing joints, {time.monotonic() - started:.0f} s")
    return 0


if __name__ == "__main__":
    sys.exit(main())
