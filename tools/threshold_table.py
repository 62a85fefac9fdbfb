#!/usr/bin/env python3
"""Compute the shipped table of scalar Gaussian thresholds (edge_monitor/stats/threshold_table.py).

For the agent's shipped detector settings — the warm-up nominal (``decision.n_nominal`` values,
calibrated at ``decision.calibrate_at``) and the steady one (``decision.steady_nominal`` values, at
``decision.steady_calibrate_at``) — it simulates ``--nominals`` × 4 detectors for ``--steps`` cycles in
standard units (edge_monitor/stats/gaussian_calibration.py) and writes, for ARL0 = 10^1.5 … 10^7 in
quarter decades, the threshold, its bootstrap standard error and how it was read, to
``edge_monitor/stats/data/gaussian_thresholds.json``. A threshold is read off directly where ≥ 30
simulated detectors alarmed (``--nominals 8192 --steps 10000``: 3.3·10⁸ detector-cycles, ≈ 30 alarms at
10⁷), else extrapolated (said in the table).

Usage: ``python tools/threshold_table.py [--nominals 8192] [--steps 10000] [--out PATH]`` (≈ 10–20 min
CPU per setting here; progress every 512 detectors).
"""

from __future__ import annotations

import os

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import argparse  # noqa: E402
import json  # noqa: E402
import logging  # noqa: E402
import sys  # noqa: E402
import time  # noqa: E402
from dataclasses import asdict  # noqa: E402
from pathlib import Path  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from edge_monitor.pipeline.detectors import DecisionConfig  # noqa: E402
from edge_monitor.stats.gaussian_calibration import (  # noqa: E402
    GaussianBudget,
    GaussianSettings,
    thresholds,
)

log = logging.getLogger("threshold_table")

TARGETS = tuple(round(10 ** (1.5 + 0.25 * k), 1) for k in range(23))      # 31.6 … 10⁷
OUT = ROOT / "edge_monitor" / "stats" / "data" / "gaussian_thresholds.json"


def shipped_settings(config: DecisionConfig | None = None) -> list[GaussianSettings]:
    """The warm-up and steady settings of the agent's scalar detectors (one per distinct healthy drift)."""
    c = config or DecisionConfig()
    out: list[GaussianSettings] = []
    for quantity in ("wear", "kl_raw", "kl_weighted"):
        d = c.detector_config(quantity)
        for n0, at, mean, sd, wander in ((d.n_nominal, d.calibrate_at, d.drift_mean, d.drift_sd, ()),
                                         (d.steady_nominal, d.steady_at, d.steady_drift_mean, d.steady_drift_sd,
                                          d.steady_wander)):
            settings = GaussianSettings(n0, d.window, d.gamma0, d.rho, d.direction, float(d.allowance),
                                        float(d.clip_sigma), at, tuple(mean), tuple(sd), tuple(wander))
            if settings not in out:
                out.append(settings)
    steady_nominal = GaussianSettings(c.steady_nominal, c.window, c.gamma0, c.rho, c.direction, float(c.allowance),
                                      float(c.clip_sigma), "nominal")      # the option without drift
    return out + ([steady_nominal] if steady_nominal not in out else [])


def entry(settings: GaussianSettings, budget: GaussianBudget) -> dict[str, object]:
    started = time.monotonic()
    found = thresholds(settings, ((1.0,),), TARGETS, budget, progress=True)      # one simulation, not two
    log.info("%s: done in %.0f s", settings, time.monotonic() - started)
    return {"settings": asdict(settings), "arl0": [t.arl0 for t in found],
            "threshold": [round(t.threshold, 4) for t in found], "h_se": [round(t.h_se, 4) for t in found],
            "method": [t.method for t in found], "events": [t.events for t in found],
            "events_min": min(t.events for t in found), "detectors": budget.nominals * budget.streams,
            "steps": budget.steps, "cpu_s": round(found[0].cpu_s, 1)}


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--nominals", type=int, default=8192)
    parser.add_argument("--steps", type=int, default=10_000)
    parser.add_argument("--out", type=Path, default=OUT)
    parser.add_argument("--recompute", action="store_true", help="recompute settings the table already holds")
    args = parser.parse_args(argv)
    logging.basicConfig(level=logging.INFO, format="%(asctime)s %(name)s %(message)s")
    budget = GaussianBudget(nominals=args.nominals, streams=4, steps=args.steps)
    kept = {}
    if args.out.exists() and not args.recompute:          # entries of settings already tabulated stay
        for e in json.loads(args.out.read_text()).get("entries", []):
            e["settings"] = {k: tuple(v) if isinstance(v, list) else v for k, v in e["settings"].items()}
            kept[GaussianSettings(**e["settings"])] = e
    entries = [kept.get(s) or entry(s, budget) for s in shipped_settings()]
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps({"command": "python tools/threshold_table.py "
                                               f"--nominals {args.nominals} --steps {args.steps}",
                                    "entries": entries}, indent=1) + "\n")
    print(f"wrote {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
