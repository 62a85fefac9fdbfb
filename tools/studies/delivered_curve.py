#!/usr/bin/env python3
"""The delivered false-alarm rate against the stated one over a range of targets, from one replay.

Each healthy joint of the kept fleet series is replayed through the agent's own detectors with a target so
deep that nothing alarms; each detector path is then counted against the threshold of every target
(studies.delivered says how; docs/DETECTION.md, "Delivered against stated, target by target"). Prints
delivered / stated per stage and quantity with a 95 % Poisson interval.

    python tools/studies/delivered_curve.py --json out.json            # 27 default robots + 3 plant weeks, ≈ 5 min
    python tools/studies/delivered_curve.py --variant 'old:decision.steady_drift={"kl_raw":[0.10,0.09]}'
"""

from __future__ import annotations

import argparse
import json
import logging
import sys
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path
from typing import Any

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))

from edge_monitor.config import config_from_mapping  # noqa: E402
from studies.delivered import (  # noqa: E402
    DEFAULT_FLEET,
    DEFAULT_PLANT,
    DEFAULT_TARGETS,
    Tally,
    check_variant,
    replay_robot,
    summary,
)
from studies.settings import parse_set, settings_from  # noqa: E402


def parse_variant(text: str) -> tuple[str, tuple[tuple[str, Any], ...]]:
    """``"NAME:decision.steady_drift={…};decision.allowance=0.5"`` → (NAME, settings)."""
    name, sep, rest = text.partition(":")
    if not sep or not name or not rest:
        raise argparse.ArgumentTypeError(f"expected NAME:TABLE.KEY=VALUE[;…], got {text!r}")
    return name, tuple(parse_set(item) for item in rest.split(";") if item.strip())


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--fleet", type=int, nargs="*", default=list(DEFAULT_FLEET), help="default robots (1 100 cycles)")
    p.add_argument("--plant", type=int, nargs="*", default=list(DEFAULT_PLANT), help="plant weeks (4 400 cycles)")
    p.add_argument("--targets", type=float, nargs="+", default=list(DEFAULT_TARGETS))
    p.add_argument("--set", dest="overrides", action="append", default=[], type=parse_set, metavar="TABLE.KEY=VALUE")
    p.add_argument("--variant", action="append", default=[], type=parse_variant, metavar="NAME:TABLE.KEY=VALUE;…",
                   help="also count the same paths against the thresholds these settings calibrate")
    p.add_argument("--jobs", type=int, default=2)
    p.add_argument("--json", type=Path)
    args = p.parse_args(argv)
    logging.basicConfig(level=logging.INFO, format="%(asctime)s %(message)s", datefmt="%H:%M:%S")
    targets = tuple(args.targets)
    overrides = tuple(args.overrides)
    variants = tuple(args.variant)
    try:
        base = config_from_mapping(settings_from(overrides)).decision
        for name, extra in variants:           # once, here: a refused variant is a message, not a worker's traceback
            check_variant(base, config_from_mapping(settings_from(overrides + extra)).decision, name)
    except ValueError as exc:                  # ConfigError is a ValueError too
        print(f"delivered_curve: {exc}", file=sys.stderr)
        return 2
    jobs = [(s, 1100, None, overrides, targets, variants) for s in args.fleet] + \
           [(s, 4400, "plant_week", overrides, targets, variants) for s in args.plant]
    total: dict[str, Tally] = {}
    try:
        with ProcessPoolExecutor(max_workers=max(1, args.jobs)) as pool:
            for result in pool.map(replay_robot, jobs):
                for key, tally in result.items():
                    total.setdefault(key, Tally()).merge(tally)
    except RuntimeError as exc:                # a replay that alarmed (statistic_paths)
        print(f"delivered_curve: {exc}", file=sys.stderr)
        return 2
    rows = summary(total, targets)
    for r in rows:
        lo, hi = r["ratio_95"]
        print(f"{r['group']:24s} T={r['target']:>8.0f}  {r['crossings']:5d} / {r['due']:8.1f} due  "
              f"delivered/stated {r['ratio']:5.2f} (95 % {lo:.2f}–{hi:.2f})")
    if args.json:
        args.json.write_text(json.dumps({"fleet": args.fleet, "plant": args.plant, "targets": targets,
                                         "overrides": dict(overrides), "rows": rows}, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
