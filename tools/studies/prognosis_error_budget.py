#!/usr/bin/env python3
"""Where the prognosis's α–λ error comes from: the agent's trend model on the same wearing joints fed the
agent's estimates, the estimates with each joint's true friction model, the true wear read through the
nominal wear coefficients, and the true wear itself (:mod:`studies.prognosis_error_budget`).

Usage: ``python tools/studies/prognosis_error_budget.py --wear 4801-4806 [--jobs 2] [--keep-series]
[--json PATH]``. The first run computes the ``known_model`` inputs (≈ 3 min per robot alone) next to the
``wear`` ones that ``tools/studies/prognosis_series.py`` keeps.
"""

from __future__ import annotations

import os

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import argparse  # noqa: E402
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
    VARIANTS,
    bias_in_band,
    joint_summary,
    nominal_equivalent,
    synthetic_rows,
)
from studies.prognosis_fleet import known_model_settings, robot_config, robot_laws  # noqa: E402
from studies.prognosis_metrics import first_alarm, law_table, replay, score_wearing  # noqa: E402
from studies.prognosis_series import fleet, rows  # noqa: E402
from studies.settings import parse_seeds  # noqa: E402


def score_robot(wear_robot: dict[str, Any], known_robot: dict[str, Any]) -> list[tuple[str, dict, dict]]:
    """Per joint of one robot: (law, {variant: WearScore}, per-joint summary)."""
    seed, config = wear_robot["seed"], PrognosisConfig()
    settings = known_model_settings(robot_config(seed, robot_laws(seed)))
    agent_rows, known_rows = rows(wear_robot), rows(known_robot)
    out = []
    for joint, joint_rows in agent_rows.items():
        law = wear_robot["laws"][joint]["law"]
        true_params = FrictionParams.from_mapping(settings["joint"][str(joint)]["friction"])
        reading = nominal_equivalent(true_params)
        rng = np.random.default_rng([seed, joint, 48])
        inputs = {"agent": joint_rows, "known_model": known_rows[joint],
                  "wear_coefficients": synthetic_rows(joint_rows, reading, rng),
                  "truth": synthetic_rows(joint_rows, None, rng)}
        scores = {}
        for variant in VARIANTS:
            alarm = first_alarm(inputs[variant])
            forecasts = replay(inputs[variant], config,
                               forecast_from=alarm.cycle if alarm else len(inputs[variant]))
            scores[variant] = score_wearing(law, inputs[variant], forecasts)
        biases = {"agent": bias_in_band(joint_rows), "known_model": bias_in_band(known_rows[joint])}
        at_critical = float(np.interp(CRITICAL_WEAR, *reading))
        out.append((law, scores, joint_summary(law, joint, seed, scores, biases, at_critical)))
    return out


def _cell(value: Any, spec: str) -> str:
    return "–" if value is None else format(value, spec)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--wear", default="4801-4806", help="seeds of wearing robots (default 4801-4806)")
    parser.add_argument("--jobs", type=int, default=2, help="processes (default 2)")
    parser.add_argument("--keep-series", action="store_true", help="use inputs kept by other code")
    parser.add_argument("--json", type=Path, help="write every number here")
    args = parser.parse_args(argv)
    logging.basicConfig(level=logging.INFO, format="%(asctime)s %(name)s %(message)s")
    logging.getLogger("edge_monitor").setLevel(logging.ERROR)
    started = time.monotonic()
    seeds = parse_seeds(args.wear)
    wearing = fleet("wear", seeds, args.jobs, args.keep_series)
    known = fleet("known_model", seeds, args.jobs, args.keep_series)
    with ProcessPoolExecutor(max(1, min(args.jobs, len(seeds)))) as pool:
        per_robot = list(pool.map(score_robot, wearing, known))
    joints = [j for robot in per_robot for j in robot]
    tables = {v: law_table([scores[v] for _, scores, _ in joints]) for v in VARIANTS}
    print(f"{'law':<12} {'joints':>6} " + " ".join(f"{v + ' α–λ / cov':>26}" for v in VARIANTS))
    for law in tables["agent"]:
        cells = [f"{_cell(tables[v][law]['alpha_lambda'], '.2f')} / {_cell(tables[v][law]['coverage'], '.2f')}"
                 for v in VARIANTS]
        print(f"{law:<12} {tables['agent'][law]['joints']:>6} " + " ".join(f"{c:>26}" for c in cells))
    summaries = [s for _, _, s in joints]
    print("\nper joint: bias (estimate − true wear, true wear 10–30) and the nominal coefficients' reading of 35")
    for s in summaries:
        passed = "".join("✓" if s["alpha_lambda"][v] else "·" for v in VARIANTS)
        print(f"  seed {s['seed']} joint {s['joint']} {s['law']:<12} α–λ {passed}  bias agent "
              f"{_cell(s['bias']['agent'], '+.1f')}, known model {_cell(s['bias']['known_model'], '+.1f')}; "
              f"35 reads {s['nominal_reading_at_critical']:.1f}")
    for variant in ("agent", "known_model"):
        b = np.array([s["bias"][variant] for s in summaries if s["bias"][variant] is not None])
        print(f"{variant}: bias over {b.size} joints: mean {b.mean():+.2f}, sd {b.std(ddof=1):.2f}, "
              f"|bias| ≤ 2 on {int(np.sum(np.abs(b) <= 2))}")
    if args.json:
        args.json.write_text(json.dumps({"tables": tables, "joints": summaries}, indent=1, default=str))
    print(f"{len(joints)} wearing joints, {time.monotonic() - started:.0f} s")
    return 0


if __name__ == "__main__":
    sys.exit(main())
