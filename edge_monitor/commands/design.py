"""``edge-monitor design``: friction speeds minimising the Cramér–Rao bound of wear (docs/ALGORITHMS.md §3).

The JSON (``--json`` on stdout, ``--out FILE`` to a file) is ``{"speeds", "wear_crlb", "wear_std",
"design_point", ...}``; ``sim-controller --speeds-from FILE`` reads its ``speeds``.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from edge_monitor.offline.experiment_design import DesignError, design_speeds
from joint_model.friction import FRICTION_NOISE_STD
from protocol.console import EXIT_FAILURE, UsageError


def add_parser(subparsers: argparse._SubParsersAction) -> argparse.ArgumentParser:
    parser = subparsers.add_parser(
        "design", help="speeds that minimise the Cramér–Rao bound of wear at a design point",
        description=__doc__, formatter_class=argparse.ArgumentDefaultsHelpFormatter)
    parser.add_argument("--points", type=int, required=True, help="number of speed levels N (≥ 1)")
    parser.add_argument("--temperature", type=float, default=40.0, help="design temperature ξ' [°C]")
    parser.add_argument("--wear", type=float, default=35.0, help="design wear level ϖ'")
    parser.add_argument("--load-mean", type=float, default=0.5, help="load torque mean μl (dimensionless)")
    parser.add_argument("--load-std", type=float, default=0.1, help="load torque std σl (dimensionless)")
    parser.add_argument("--noise-std", type=float, default=FRICTION_NOISE_STD, help="friction datum noise σ")
    parser.add_argument("--speed-min", type=float, default=1.0, help="lowest speed [rad/s]")
    parser.add_argument("--speed-max", type=float, default=280.0, help="highest speed [rad/s]")
    parser.add_argument("--min-separation", type=float, default=5.0, help="minimum speed separation δ [rad/s]")
    parser.add_argument("--seed", type=int, default=0, help="seed of the random optimiser starts (N ≥ 3)")
    parser.add_argument("--json", action="store_true", help="print the design as JSON")
    parser.add_argument("-o", "--out", type=Path, help="also write the JSON to this file (for --speeds-from)")
    parser.set_defaults(func=run)
    return parser


#: Most speed levels a design may have (a test cycle holds a few; segment codes allow < 200).
MAX_POINTS = 100


def run(args: argparse.Namespace) -> int:
    if not 1 <= args.points <= MAX_POINTS:
        raise UsageError(f"--points {args.points}: give 1 … {MAX_POINTS} speed levels")
    if args.seed < 0:
        raise UsageError(f"--seed {args.seed}: give an integer ≥ 0")
    try:
        result = design_speeds(args.points, temperature=args.temperature, wear=args.wear,
                               load_mean=args.load_mean, load_std=args.load_std, noise_std=args.noise_std,
                               speed_min=args.speed_min, speed_max=args.speed_max,
                               min_separation=args.min_separation, seed=args.seed)
    except DesignError as exc:      # the options ask for something impossible
        raise UsageError(str(exc)) from None
    payload = result.to_json()
    text = json.dumps(payload, indent=2)
    if args.out is not None:
        try:
            args.out.write_text(text + "\n", encoding="utf-8")
        except OSError as exc:
            print(f"edge-monitor design: --out: cannot write {args.out}: {exc}", file=sys.stderr)
            return EXIT_FAILURE
    if args.json:
        print(text)
    else:
        speeds = ", ".join(f"{v:.2f}" for v in result.speeds)
        print(f"speeds [rad/s]: {speeds}")
        print(f"Cramér–Rao bound of wear: variance {result.wear_crlb:.4g}, std {result.wear_std:.4g} "
              f"(at ξ'={result.design_point.temperature} °C, ϖ'={result.design_point.wear})")
    return 0
