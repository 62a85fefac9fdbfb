#!/usr/bin/env python3
"""How the detector inputs of warm healthy joints move after their steady nominal is learned, on default
robots at one load range: the numbers behind ``[decision.steady_wander]`` and the default robots'
``[decision.steady_drift]`` (docs/DETECTION.md, "The steady stage's healthy drift"); the shipped drift is a
plant week's, from ``tools/studies/plant_drift_study.py``.

For every joint of the cached fast-path series (studies.series; default seeds 101–108, 6 joints,
1 100 cycles), in the units the detectors watch (the wear score; the logs of the KL distances): the
values of cycles ``--learn-from`` … +240 are the steady nominal (every joint of the default robot has
settled by then), the rest are watched. Per input it prints, over joints:

* the shift of the watched values' mean from the learned mean, in learned standard deviations (mean and
  sd over joints: the drift; the learning error is part of the sd, and the calibration simulates it);
* the lag-1 autocorrelation of the watched values (each joint's own mean removed);
* the variance ratio k·var(k-cycle mean)/var at k = 1, 5, 10, 30, 60, 100 (1 for independent values;
  larger values mean a slow wander; at k ≥ 60 the few blocks per joint bias it low).

Usage: ``python tools/studies/steady_drift_study.py [--seeds 101-108] [--joints 6] [--cycles 1100]``; seconds once
the series are cached (minutes per robot to compute them).
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path
from typing import Any

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))

from studies.series import fleet  # noqa: E402
from studies.settings import parse_seeds  # noqa: E402
from studies.statistics import variance_ratio  # noqa: E402

INPUTS = ("wear_score", "kl_raw", "kl_weighted")
LOGS = ("kl_raw", "kl_weighted")
BLOCKS = (1, 5, 10, 30, 60, 100)
STEADY_NOMINAL = 240


def watched(rows: list[dict[str, float]], name: str) -> tuple[np.ndarray, np.ndarray]:
    """(cycles, values in the detector's units) of one joint, finite values only."""
    cycles = np.array([r["cycle"] for r in rows], dtype=float)
    values = np.array([np.nan if r.get(name) is None else r[name] for r in rows], dtype=float)
    if name in LOGS:
        with np.errstate(divide="ignore", invalid="ignore"):
            values = np.log(values)
    ok = np.isfinite(values)
    return cycles[ok], values[ok]


def joint_numbers(cycles: np.ndarray, values: np.ndarray, learn_from: int) -> dict[str, Any] | None:
    learn = values[(cycles >= learn_from) & (cycles < learn_from + STEADY_NOMINAL)]
    watch = values[cycles >= learn_from + STEADY_NOMINAL]
    if learn.size < 0.8 * STEADY_NOMINAL or watch.size < 2 * max(BLOCKS):
        return None
    z = (watch - learn.mean()) / learn.std(ddof=1)
    centred = z - z.mean()
    return {"shift": float(z.mean()), "lag1": float(np.corrcoef(centred[:-1], centred[1:])[0, 1]),
            "ratios": [variance_ratio(centred, k) for k in BLOCKS]}


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--seeds", default="101-108")
    parser.add_argument("--joints", type=int, default=6)
    parser.add_argument("--cycles", type=int, default=1100)
    parser.add_argument("--learn-from", type=int, default=350, help="first cycle of the steady nominal")
    args = parser.parse_args(argv)
    robots = fleet(parse_seeds(args.seeds), args.cycles, args.joints)
    print(f"| input | joints | shift mean [σ] | shift sd [σ] | lag-1 | variance ratio at k = "
          f"{', '.join(map(str, BLOCKS))} |")
    print("|---|---|---|---|---|---|")
    for name in INPUTS:
        found = [n for robot in robots for rows in robot.values()
                 if (n := joint_numbers(*watched(rows, name), args.learn_from)) is not None]
        shifts = np.array([f["shift"] for f in found])
        ratios = np.mean([f["ratios"] for f in found], axis=0)
        print(f"| {name} | {len(found)} | {shifts.mean():+.3f} | {shifts.std(ddof=1):.3f} | "
              f"{np.mean([f['lag1'] for f in found]):+.3f} | {', '.join(f'{r:.2f}' for r in ratios)} |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
