#!/usr/bin/env python3
"""Where the warm-up KL detectors should hold: the drift of a healthy joint's KL distances against how far
its smoothed temperature is above the span its warm-up nominal was learned in, and when the shipped holds
begin (docs/DETECTION.md, "Operating conditions", "Why 6 °C").

Reads the per-cycle quantities studies.series keeps (computed there if missing). Per joint the
warm-up nominal is its first ``decision.n_nominal`` values (log of the KL distance), the span is the
smoothed temperature's (edge_monitor/pipeline/hold_temperature.py) over those cycles, and every later
cycle up to ``--until`` is binned by the smoothed temperature's excess over the span's top. Per bin:

* the mean over joints of each joint's mean shift (σ of its learned values) ± its spread over joints, and
  the share of joints beyond the detectors' 0.75 σ allowance;
* the share of the bin's cycles the former hold tested: a raw cycle temperature at most max(2 °C, 10 % of
  the raw span) above the raw span's top.

Then the shipped :class:`~edge_monitor.pipeline.detectors.DetectorBank` over each joint (studies.bank_replay): the first cycle a
warm-up detector of ``--quantity`` holds and the share of its warm-up cycles 90–750 held.

Usage: ``python tools/studies/hold_margin_study.py --seeds 101-127 [--quantity kl_weighted] [--json OUT]``
(≈ 4 min for 27 kept robots here).
"""

from __future__ import annotations

import argparse
import json
import logging
import math
import sys
from pathlib import Path
from typing import Any

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))

from edge_monitor.pipeline.decision_config import DecisionConfig  # noqa: E402
from edge_monitor.pipeline.hold_temperature import HoldTemperature  # noqa: E402
from studies.bank_replay import new_bank, replay_bank  # noqa: E402
from studies.series import robot_series  # noqa: E402
from studies.settings import parse_seeds  # noqa: E402

#: Bins of the smoothed temperature's excess over the learning span's top [°C].
BINS = ((-math.inf, 0.0), (0.0, 2.0), (2.0, 4.0), (4.0, 6.0), (6.0, 8.0), (8.0, 10.0), (10.0, 14.0), (14.0, 20.0))
#: The drift allowance the warm-up thresholds are calibrated at [σ].
ALLOWANCE = 0.75


def joint_rows(rows: list[dict[str, float]], quantity: str, n_nominal: int, until: int
               ) -> list[tuple[float, float, bool]]:
    """Per cycle after the nominal (up to cycle ``until``): (shift [σ of the learned values], smoothed excess
    over the smoothed span's top [°C], whether the raw per-cycle hold would have tested it)."""
    rows = [r for r in rows if int(r["cycle"]) < until]
    raw = np.array([r["motor_temperature"] for r in rows], dtype=float)
    value = np.log(np.array([r[quantity] for r in rows], dtype=float))
    if raw.size <= n_nominal or not np.all(np.isfinite(raw[:n_nominal])):
        return []
    smoothing = HoldTemperature()
    smoothed = np.array([smoothing.update(t) for t in raw], dtype=float)
    learned = value[:n_nominal]
    shift = (value - learned.mean()) / learned.std(ddof=1)
    raw_lo, raw_hi = raw[:n_nominal].min(), raw[:n_nominal].max()
    tested = raw <= raw_hi + max(2.0, 0.1 * (raw_hi - raw_lo))
    excess = smoothed - smoothed[:n_nominal].max()
    return [(float(s), float(e), bool(t)) for s, e, t in zip(shift[n_nominal:], excess[n_nominal:], tested[n_nominal:])]


def drift_table(per_joint: list[list[tuple[float, float, bool]]]) -> list[dict[str, Any]]:
    """Per bin: joints, the mean ± sd over joints of their mean shift, the share beyond the allowance and
    the share of the bin's cycles the raw hold tested."""
    out = []
    for lo, hi in BINS:
        means, cycles, tested = [], 0, 0
        for rows in per_joint:
            inside = [(s, t) for s, e, t in rows if lo <= e < hi]
            cycles += len(inside)
            tested += sum(t for _, t in inside)
            if len(inside) >= 5:
                means.append(float(np.mean([s for s, _ in inside])))
        m = np.array(means)
        out.append({"bin": [lo, hi], "joints": int(m.size), "mean": float(m.mean()) if m.size else None,
                    "sd": float(m.std()) if m.size else None,
                    "beyond_allowance": float((m > ALLOWANCE).mean()) if m.size else None,
                    "cycles": cycles, "raw_hold_tested": tested / cycles if cycles else None})
    return out


def hold_onset(rows: list[dict[str, float]], quantity: str, config: DecisionConfig) -> tuple[int | None, float]:
    """The shipped bank over one joint: the first cycle ``quantity``'s detector holds, and the share of its
    warm-up cycles 90–750 it holds."""
    bank = new_bank(config)
    first, warm_up, held = None, 0, 0
    for step in replay_bank(bank, rows):
        is_held = step.decisions[quantity].reason.startswith("held")
        if is_held and first is None:
            first = step.cycle
        if 90 <= step.cycle < 750 and bank.detectors[quantity].stage != "steady":
            warm_up += 1
            held += is_held
    return first, held / warm_up if warm_up else math.nan


def markdown(table: list[dict[str, Any]], quantity: str) -> str:
    label = lambda b: "in span" if b[0] == -math.inf else f"{b[0]:g}–{b[1]:g} °C"   # noqa: E731
    head = "| smoothed temperature above the smoothed learning span | " + " | ".join(label(r["bin"]) for r in table)
    cells = [f"{r['mean']:+.2f} ± {r['sd']:.2f} ({100 * r['beyond_allowance']:.0f} %)" if r["joints"] else "—"
             for r in table]
    tested = [f"{100 * r['raw_hold_tested']:.1f} %" if r["cycles"] else "—" for r in table]
    return "\n".join([head + " |", "|---" * (len(table) + 1) + "|",
                      f"| log {quantity}: mean ± sd over joints (share beyond the {ALLOWANCE} σ allowance) | "
                      + " | ".join(cells) + " |",
                      "| share of those cycles the raw hold (before) tested | " + " | ".join(tested) + " |"])


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--seeds", default="101-127", help="kept robots, e.g. 101-127 (studies.series)")
    ap.add_argument("--cycles", type=int, default=1100)
    ap.add_argument("--joints", type=int, default=6)
    ap.add_argument("--quantity", default="kl_weighted", choices=("kl_raw", "kl_weighted"))
    ap.add_argument("--until", type=int, default=900, help="last cycle of the drift table (exclusive)")
    ap.add_argument("--json", type=Path)
    args = ap.parse_args(argv)
    logging.basicConfig(level=logging.WARNING, format="%(asctime)s %(name)s %(message)s")
    config = DecisionConfig()
    per_joint, onsets, shares = [], [], []
    for seed in parse_seeds(args.seeds):
        for rows in robot_series(seed, args.cycles, args.joints).values():
            per_joint.append(joint_rows(rows, args.quantity, config.n_nominal, args.until))
            first, share = hold_onset(rows, args.quantity, config)
            onsets.append(math.nan if first is None else first)
            shares.append(share)
    table = drift_table(per_joint)
    print(markdown(table, args.quantity))
    on, sh = np.array(onsets, dtype=float), np.array(shares, dtype=float)
    print(f"\n{on.size} joints: holds from cycle {np.nanmedian(on):.0f} ({np.nanpercentile(on, 10):.0f}–"
          f"{np.nanpercentile(on, 90):.0f}, 10–90 %; never: {int(np.isnan(on).sum())}), "
          f"{100 * np.nanmedian(sh):.0f} % ({100 * np.nanpercentile(sh, 10):.0f}–{100 * np.nanpercentile(sh, 90):.0f} %) "
          f"of the warm-up cycles 90–750 held")
    if args.json:
        args.json.write_text(json.dumps({"quantity": args.quantity, "table": table, "onsets": onsets,
                                         "held_share": shares}, default=str, indent=1) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
