#!/usr/bin/env python3
"""Compute the shipped table of Gaussian thresholds (edge_monitor/stats/threshold_table.py).

For the agent's shipped detector settings — the warm-up nominal (``decision.n_nominal`` values,
calibrated at ``decision.calibrate_at``) and the steady one (``decision.steady_nominal`` values, at
``decision.steady_calibrate_at``), for the scalar detectors and for the joint vector at each
correlation of its KL axes in ``--vector-rho`` — it simulates ``--nominals`` × 4 detectors for
``--steps`` cycles in standard units (edge_monitor/stats/gaussian_calibration.py) and writes, for
ARL0 = 10^1.5 … 10^7 in quarter decades, the threshold, its bootstrap standard error and how it was
read, to ``edge_monitor/stats/data/gaussian_thresholds.json``. A threshold is read off directly where
≥ 30 simulated detectors alarmed, else extrapolated (said in the table). Entries the table already
holds stay unless ``--recompute``; ``--jobs`` computes entries in parallel processes.

Usage: ``python tools/studies/threshold_table.py [--nominals 4096] [--steps 4000] [--jobs 2] [--only
scalar|vector] [--stage warm-up|steady] [--quantity Q] [--out PATH]`` (scalar entries ≈ 3–8 min, vector ones ≈ 10–20 min CPU each here;
progress every 512 detectors).
"""

from __future__ import annotations

import os

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import argparse  # noqa: E402
import concurrent.futures  # noqa: E402
import json  # noqa: E402
import logging  # noqa: E402
import sys  # noqa: E402
import time  # noqa: E402
from dataclasses import asdict  # noqa: E402
from pathlib import Path  # noqa: E402
from typing import Any  # noqa: E402

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT))

from edge_monitor.pipeline.detectors import DecisionConfig  # noqa: E402
from edge_monitor.stats.gaussian_calibration import (  # noqa: E402
    DRIFT_TILTS,
    GaussianBudget,
    GaussianSettings,
    thresholds,
)
from edge_monitor.stats.threshold_table import (  # noqa: E402
    entry_correlation,
    entry_rho,
    entry_settings,
    key,
    tabulated_correlation,
)

log = logging.getLogger("threshold_table")

TARGETS = tuple(round(10 ** (1.5 + 0.25 * k), 1) for k in range(23))      # 31.6 … 10⁷
OUT = ROOT / "edge_monitor" / "stats" / "data" / "gaussian_thresholds.json"


def shipped_settings(config: DecisionConfig | None = None, quantities: tuple[str, ...] = ("wear", "kl_raw",
                                                                                        "kl_weighted")
                     ) -> list[GaussianSettings]:
    """The warm-up and steady settings of the agent's detectors of ``quantities`` (one per distinct
    healthy drift), on joints with a motor temperature and without one."""
    c = config or DecisionConfig()
    out: list[GaussianSettings] = []
    for quantity, friction in ((q, f) for q in quantities for f in (False, True)):
        d = c.detector_config(quantity, friction_temperature=friction)
        for stage in ("warm-up", "steady"):
            settings = d.gaussian_settings(stage)
            if settings not in out:
                out.append(settings)
    return out


def scalar_settings(config: DecisionConfig | None = None) -> list[GaussianSettings]:
    """:func:`shipped_settings` of the scalar detectors, and the steady option without drift."""
    c = config or DecisionConfig()
    out = shipped_settings(c)
    steady_nominal = GaussianSettings(c.steady_nominal, c.window, c.gamma0, c.rho, c.direction, float(c.allowance),
                                      float(c.clip_sigma), "nominal",      # the option without drift
                                      transform=c.detector_config("wear").steady_learned_transform)
    return out + ([steady_nominal] if steady_nominal not in out else [])


def entry(settings: GaussianSettings, budget: GaussianBudget, dim: int = 1, rho: float = 0.0) -> dict[str, Any]:
    """One table entry: ``settings`` for a ``dim``-dimensional detector whose KL axes correlate by ``rho``."""
    started = time.monotonic()
    corr = tabulated_correlation(rho, dim)
    found = thresholds(settings, corr, TARGETS, budget, progress=True)      # one simulation, not two
    log.info("%s (d = %d, rho = %.2f): done in %.0f s", settings, dim, rho, time.monotonic() - started)
    return {"settings": asdict(settings), "correlation": [list(row) for row in corr], "arl0": [t.arl0 for t in found],
            "threshold": [round(t.threshold, 4) for t in found], "h_se": [round(t.h_se, 4) for t in found],
            "method": [t.method for t in found], "events": [t.events for t in found],
            "events_min": min(t.events for t in found), "detectors": budget.nominals * budget.streams,
            "steps": budget.steps, "drift_tilts": list(budget.drift_tilts), "cpu_s": round(found[0].cpu_s, 1)}


def _entry_key(e: dict[str, Any]) -> tuple[str, float]:
    """(settings key with the dimension, ρ) of a table entry."""
    return key(entry_settings(e), len(entry_correlation(e))), round(entry_rho(e), 6)


def wanted(only: str, vector_rho: list[float], stage: str = "all",
           quantity: str | None = None) -> list[tuple[GaussianSettings, int, float]]:
    """The (settings, dim, ρ) the table should hold (of the warm-up or the steady nominal only: ``stage``;
    of one quantity's detector only: ``quantity``)."""
    out: list[tuple[GaussianSettings, int, float]] = []
    if only in ("all", "scalar"):
        out += [(s, 1, 0.0) for s in scalar_settings()]
    if only in ("all", "vector"):
        dim = DecisionConfig().detector_config("joint").dim
        out += [(s, dim, rho) for s in shipped_settings(quantities=("joint",)) for rho in vector_rho]
    mine = shipped_settings(quantities=(quantity,)) if quantity else None
    return [(s, dim, rho) for s, dim, rho in out if in_stage(s, stage) and (mine is None or s in mine)]


def in_stage(settings: GaussianSettings, stage: str) -> bool:
    """Whether ``settings`` are the warm-up nominal's or the steady one's, as ``stage`` asks ("all": both):
    the warm-up nominal learns ``decision.n_nominal`` values, the steady one more."""
    return stage == "all" or (settings.n0 == DecisionConfig().n_nominal) == (stage == "warm-up")


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--nominals", type=int, default=4096)
    parser.add_argument("--steps", type=int, default=4000)
    parser.add_argument("--vector-rho", default="0,0.5,0.7,0.9",
                        help="correlations of the joint vector's KL axes to tabulate (comma-separated)")
    parser.add_argument("--only", choices=("all", "scalar", "vector"), default="all")
    parser.add_argument("--stage", choices=("all", "warm-up", "steady"), default="all",
                        help="only the entries of the warm-up or of the steady nominal")
    parser.add_argument("--quantity", choices=("wear", "kl_raw", "kl_weighted", "joint"), default=None,
                        help="only the entries of this quantity's detector (a deeper simulation of one entry)")
    parser.add_argument("--drift-tilts", default="0",
                        help="importance sampling of the healthy drift: the proposals' tilts, comma-separated (0, "
                             "the default: plain draws; the shipped wide-drift entries: "
                             + ",".join(f"{t:g}" for t in DRIFT_TILTS) + ")")
    parser.add_argument("--jobs", type=int, default=1, help="entries computed in parallel processes")
    parser.add_argument("--out", type=Path, default=OUT)
    parser.add_argument("--recompute", action="store_true", help="recompute entries the table already holds")
    args = parser.parse_args(argv)
    logging.basicConfig(level=logging.INFO, format="%(asctime)s %(name)s %(message)s")
    try:
        budget = GaussianBudget(nominals=args.nominals, streams=4, steps=args.steps,
                                drift_tilts=tuple(float(x) for x in args.drift_tilts.split(",") if x.strip()))
    except ValueError as exc:
        parser.error(f"--nominals/--drift-tilts: {exc}")
    kept: dict[tuple[str, float], dict[str, Any]] = {}
    commands: list[str] = []
    if args.out.exists():
        old = json.loads(args.out.read_text())
        kept = {_entry_key(e): e for e in old.get("entries", [])}
        commands = list(old.get("commands") or ([old["command"]] if old.get("command") else []))
    todo = wanted(args.only, [float(x) for x in args.vector_rho.split(",") if x.strip()], args.stage, args.quantity)
    missing = [(s, dim, rho) for s, dim, rho in todo if args.recompute or (key(s, dim), round(rho, 6)) not in kept]
    log.info("%d entries to compute, %d kept", len(missing), len(kept))
    with concurrent.futures.ProcessPoolExecutor(max_workers=max(1, args.jobs)) as pool:
        jobs = [pool.submit(entry, s, budget, dim, rho) for s, dim, rho in missing]
        for job in concurrent.futures.as_completed(jobs):
            e = job.result()
            kept[_entry_key(e)] = e
    args.out.parent.mkdir(parents=True, exist_ok=True)
    if missing:                          # what computed the entries, in order (each entry says its budget)
        commands.append("python tools/studies/threshold_table.py " + " ".join(argv if argv is not None else sys.argv[1:]))
    args.out.write_text(json.dumps({"commands": commands, "entries": list(kept.values())}, indent=1) + "\n")
    print(f"wrote {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
