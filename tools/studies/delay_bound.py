#!/usr/bin/env python3
"""Detection delay against its bound (docs/DETECTION.md, "Detection delay against the bound"; the method is
studies/delay_bound.py): slow, medium and fast wear ramps and a step, starting in the warm-up, in the steady
stage, after an overnight stop and after a load change; per case the agent's first alarm next to an oracle
CUSUM that knows the healthy and worn densities of the same per-cycle quantities, at the same target run length.

Usage: ``python tools/studies/delay_bound.py --seeds 7201,7202 [--situations warm-up,steady,...] [--set
decision.budget_period=week] [--jobs 2] [--json OUT]``. Each robot is simulated twice per situation (healthy and
worn, ≈ 1 000–1 750 cycles each; kept in .cache/fleet_series/ once per code version).
"""

from __future__ import annotations

import os

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")     # tiny matrices: threaded BLAS only spins

import argparse  # noqa: E402
import json  # noqa: E402
import logging  # noqa: E402
import statistics  # noqa: E402
import sys  # noqa: E402
from concurrent.futures import ProcessPoolExecutor  # noqa: E402
from dataclasses import asdict  # noqa: E402
from pathlib import Path  # noqa: E402

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT))

from edge_monitor.config import config_from_mapping  # noqa: E402
from studies.delay_bound import RAMPS, SITUATIONS, Delay, situation_delays  # noqa: E402
from studies.settings import parse_seeds, parse_set, settings_from  # noqa: E402


def _job(args: tuple[int, str, tuple]) -> list[Delay]:
    seed, situation, overrides = args
    return situation_delays(seed, situation, config_from_mapping(settings_from(overrides)).decision)


def _cell(values: list[int | None], wear: list[float | None]) -> str:
    found = [v for v in values if v is not None]
    if not found:
        return "none"
    text = f"{statistics.median(found):.0f}"
    w = [x for x in wear if x is not None]
    return text + (f" ({statistics.median(w):.1f})" if w else "") + ("" if len(found) == len(values) else
                                                                     f", {len(values) - len(found)} missed")


def table(delays: list[Delay]) -> str:
    """Median over seeds: delay [cycles] (true wear then) of the agent and of the oracle, and their ratio."""
    lines = ["| starts | wear | agent: delay (wear) | oracle: delay (wear) | agent / oracle |", "|---|---|---|---|---|"]
    for situation in SITUATIONS:
        for ramp, _, _ in RAMPS:
            mine = [d for d in delays if d.situation == situation and d.ramp == ramp]
            if not mine:
                continue
            ratios = [d.agent / d.oracle for d in mine if d.agent is not None and d.oracle]
            ratio = f"{statistics.median(ratios):.2f}" if ratios else "–"
            lines.append(f"| {situation} | {ramp} | {_cell([d.agent for d in mine], [d.agent_wear for d in mine])} | "
                         f"{_cell([d.oracle for d in mine], [d.oracle_wear for d in mine])} | {ratio} |")
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--seeds", required=True)
    parser.add_argument("--situations", default=",".join(SITUATIONS),
                        help=f"comma-separated, of: {', '.join(SITUATIONS)}")
    parser.add_argument("--set", action="append", default=[], type=parse_set, metavar="TABLE.KEY=VALUE")
    parser.add_argument("--jobs", type=int, default=2)
    parser.add_argument("--json", type=Path)
    args = parser.parse_args(argv)
    logging.basicConfig(level=logging.INFO, format="%(asctime)s %(name)s %(message)s")
    situations = [s.strip() for s in args.situations.split(",") if s.strip()]
    unknown = [s for s in situations if s not in SITUATIONS]
    if unknown:
        parser.error(f"--situations: unknown {unknown}; known: {list(SITUATIONS)}")
    jobs = [(seed, s, tuple(args.set)) for seed in parse_seeds(args.seeds) for s in situations]
    with ProcessPoolExecutor(max(1, args.jobs)) as pool:
        delays = [d for result in pool.map(_job, jobs) for d in result]
    print(table(delays))
    for d in delays:
        print(f"seed-case {d.situation:>20} {d.ramp:>6} joint {d.joint}: agent {d.agent} ({d.agent_quantity}, "
              f"wear {d.agent_wear}), oracle {d.oracle} (wear {d.oracle_wear})")
    if args.json:
        args.json.write_text(json.dumps([asdict(d) for d in delays], indent=1) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
