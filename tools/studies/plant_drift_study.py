#!/usr/bin/env python3
"""How the steady detectors' inputs drift over a plant's week: the numbers behind the shipped
``[decision.steady_drift]`` (docs/DETECTION.md, "The steady stage on a plant's week").

For every joint of the kept fast-path series of a scenario (studies.series; default the plant
week, seeds 401–407, 4 400 cycles), the agent's own :class:`DetectorBank` (shipped defaults) is replayed;
each cycle a scalar detector tests in its steady stage is read in that detector's standard units (the
learned Yeo–Johnson transform, then the learned mean and standard deviation), less the temperature slack it is
tested with (edge_monitor/pipeline/temperature_slack.py; the week's stops are pauses, as the agent sees them). Per operating period
(``--periods``: the cycles where the week changes, by default the product change at 2 000 and the hot
day 2 600–3 200) it prints, over joints, the mean ± sd of each joint's period mean, and the variance
ratios k·var(k-cycle mean)/var of the values within a period (each period's mean removed). Last, per
input, the pooled drift the calibration is given: the mean and sd of the (joint, period) means weighted
by their cycles, the sd without the learning error of a 240-value nominal and the period means' own
noise (both with the input's within-period variance ratio at k = 60).

Usage: ``python tools/studies/plant_drift_study.py [--seeds 401-407] [--scenario plant_week] [--cycles 4400]
[--periods 2000,2600,3200] [--jobs 2]``; ≈ 5 min for 7 plant weeks once their series are kept.
"""

from __future__ import annotations

import os

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import argparse  # noqa: E402
import logging  # noqa: E402
import sys  # noqa: E402
from concurrent.futures import ProcessPoolExecutor  # noqa: E402
from pathlib import Path  # noqa: E402
from typing import Any  # noqa: E402

import numpy as np  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))

from edge_monitor.config import config_from_mapping  # noqa: E402
from edge_monitor.features.registry import QUANTITIES  # noqa: E402
from studies.bank_replay import new_bank, replay_bank, standard_units  # noqa: E402
from studies.robots import kept_robot_pauses  # noqa: E402
from studies.series import robot_series  # noqa: E402
from studies.settings import parse_seeds  # noqa: E402
from studies.statistics import variance_ratio  # noqa: E402

#: The scalar detectors (each watches one series field, ``QUANTITIES[name].inputs[0]``).
INPUTS = ("wear", "kl_raw", "kl_weighted")
BLOCKS = (5, 10, 30, 60)
#: Fewest k-cycle blocks a variance ratio is read from.
MIN_BLOCKS = 10
STEADY_NOMINAL = 240

Rows = list[tuple[str, tuple[int, int], int, float]]   # (detector, (seed, joint), cycle, value in standard units)


def steady_values(seed: int, scenario: str | None, cycles: int) -> Rows:
    """Every tested steady value of one robot, less its temperature slack, in its detector's standard units
    (the robot's stops are pauses, as the agent sees them)."""
    decision = config_from_mapping({}).decision
    stops = kept_robot_pauses(seed, cycles, scenario)
    out: Rows = []
    for joint, rows in robot_series(seed, cycles, 6, scenario).items():
        bank = new_bank(decision)
        slack: dict[str, float] = {}

        def before(row: dict[str, Any]) -> dict[str, Any]:
            for name in INPUTS:                # the slack this cycle's value is tested with (before the update)
                detector = bank.detectors[name]
                given = bank.spans.slack(name, QUANTITIES[name].inputs, detector, bank.smoothed)
                slack[name] = given[0] if given else 0.0
            return row

        for step in replay_bank(bank, rows, joint, values=before, pauses=stops):
            watched = bank.watched(step.row)
            for name in INPUTS:
                det = bank.detectors[name]
                value = watched.get(QUANTITIES[name].inputs[0], np.nan)
                if det.stage != "steady" or det.density is None or step.decisions[name].statistic is None \
                        or not np.isfinite(value):
                    continue
                out.append((name, (seed, joint), step.cycle, standard_units(det, value) - slack[name]))
    return out


def period_of(cycle: int, edges: list[int]) -> int:
    return int(np.searchsorted(edges, cycle, side="right"))


def input_summary(rows: Rows, name: str, edges: list[int]) -> dict[str, Any]:
    """One input's numbers: per period the mean and sd over joints of the joints' period means
    (``periods``, None where no joint has more than 50 values there), the within-period variance ratios at
    :data:`BLOCKS` (``ratios``) and the pooled drift ``(mean, sd)`` (see the module docstring)."""
    by_joint: dict[tuple[int, int], list[tuple[int, float]]] = {}
    for q, joint, cycle, z in rows:
        if q == name:
            by_joint.setdefault(joint, []).append((cycle, z))
    means: dict[int, list[float]] = {}
    weighted: list[tuple[float, int]] = []
    ratios: list[list[float]] = []
    for values in by_joint.values():
        periods = np.array([period_of(c, edges) for c, _ in values])
        z_arr = np.array([v for _, v in values])
        centred = []
        for p in range(len(edges) + 1):
            part = z_arr[periods == p]
            if part.size > 50:
                means.setdefault(p, []).append(float(part.mean()))
                weighted.append((float(part.mean()), int(part.size)))
                centred.append(part - part.mean())
        if centred:
            flat = np.concatenate(centred)
            ratios.append([variance_ratio(flat, k) if flat.size >= MIN_BLOCKS * k else float("nan") for k in BLOCKS])
    if not weighted:
        return {"periods": [None] * (len(edges) + 1), "ratios": [], "drift": (float("nan"), float("nan"))}
    m = np.array([w[0] for w in weighted])
    n = np.array([w[1] for w in weighted], dtype=float)
    mean = float((n * m).sum() / n.sum())
    var = float((n * (m - mean) ** 2).sum() / n.sum())
    ratio = float(np.nanmean([r[-1] for r in ratios]))
    noise = ratio / STEADY_NOMINAL + ratio / float(n.mean())
    return {"periods": [(float(np.mean(means[p])), float(np.std(means[p]))) if p in means else None
                        for p in range(len(edges) + 1)],
            "ratios": [float(r) for r in np.nanmean(ratios, axis=0)],
            "drift": (mean, float(np.sqrt(max(var - noise, 0.0))))}


def report(rows: Rows, edges: list[int]) -> None:
    names = [f"< {edges[0]}"] + [f"{a}–{b}" for a, b in zip(edges, edges[1:])] + [f"≥ {edges[-1]}"]
    print("| input | " + " | ".join(names) + " | within a period: k·var(k-mean)/var at k = "
          + ", ".join(map(str, BLOCKS)) + " | pooled drift (mean, sd beyond the noise) |")
    print("|---" * (len(names) + 3) + "|")
    for name in INPUTS:
        summary = input_summary(rows, name, edges)
        cells = ["–" if cell is None else f"{cell[0]:+.2f} ± {cell[1]:.2f}" for cell in summary["periods"]]
        mean, sd = summary["drift"]
        print(f"| {name} | " + " | ".join(cells) + " | " + ", ".join(f"{r:.2f}" for r in summary["ratios"])
              + f" | ({mean:+.3f}, {sd:.3f}) |")


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--seeds", default="401-407")
    parser.add_argument("--scenario", default="plant_week")
    parser.add_argument("--cycles", type=int, default=4400)
    parser.add_argument("--periods", default="2000,2600,3200", help="cycles where an operating period begins")
    parser.add_argument("--jobs", type=int, default=2)
    args = parser.parse_args(argv)
    logging.basicConfig(level=logging.WARNING)
    seeds = parse_seeds(args.seeds)
    edges = sorted(int(x) for x in args.periods.split(","))
    with ProcessPoolExecutor(max(1, min(args.jobs, len(seeds)))) as pool:
        rows = [r for robot in pool.map(steady_values, seeds, [args.scenario] * len(seeds),
                                        [args.cycles] * len(seeds)) for r in robot]
    report(rows, edges)
    return 0


if __name__ == "__main__":
    sys.exit(main())
