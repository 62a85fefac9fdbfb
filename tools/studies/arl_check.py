#!/usr/bin/env python3
"""The shipped thresholds against an independent simulation: is the run length they state delivered?

For every entry of the shipped table (edge_monitor/stats/data/gaussian_thresholds.json: the scalar
detectors' warm-up and steady settings, the joint vector at each tabulated KL correlation) and each
target ARL0 in ``--targets``, the threshold is read from the table as the agent reads it, and then
``--detectors`` detectors are simulated, each learning its own nominal from N0 values and then watching
its stream for ``--cycles`` cycles, with the stream law the entry was calibrated for (at the nominal,
at the allowance boundary, or the healthy drift and slow wander; a steady scalar detector learning its
Yeo–Johnson transform from its own learning values first; a warm-up scalar whose law is stated in its
nominal's learned units, an exact nominal and each stream's spread drawn from that law). Unlike the calibration, which reads
first passages from a fresh start, every alarm here is acknowledged and the statistic restarts on the
same nominal, as the agent's are; and the draws come from another seed. Delivered ARL0 = detector-cycles
/ alarms, with a 95 % interval from the alarms counted per detector (clustered: a badly learned nominal
alarms again and again).

Usage: ``python tools/studies/arl_check.py [--targets 1e3,1e4,1e5] [--only scalar|vector] [--stage
warm-up|steady] [--rho 0.5] [--transform yeo-johnson|none] [--learn-transform] [--detectors 16384] [--json OUT]`` (scalars: ≈ 2 min per entry and target here; the vector ≈ 4–10× that, run it with
``--detectors 1024``; a status line per entry).
"""

from __future__ import annotations

import os

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import argparse  # noqa: E402
import json  # noqa: E402
import logging  # noqa: E402
import math  # noqa: E402
import sys  # noqa: E402
import time  # noqa: E402
from dataclasses import replace  # noqa: E402
from pathlib import Path  # noqa: E402
from typing import Any  # noqa: E402

import numpy as np  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))

from threshold_table import in_stage  # noqa: E402  (tools/studies/threshold_table.py)

from edge_monitor.stats import gaussian_calibration as gc  # noqa: E402
from edge_monitor.stats import gaussian_fleet as gf  # noqa: E402
from edge_monitor.stats.gaussian_calibration import GaussianSettings  # noqa: E402
from edge_monitor.stats.learned_axes import independent_learned_axes  # noqa: E402
from edge_monitor.stats.threshold_table import entries_by_key, entry_correlation, entry_settings, lookup  # noqa: E402

log = logging.getLogger("arl_check")

#: Seed of the check's draws (the calibration's is gaussian_fleet.SEED).
CHECK_SEED = 20261127
#: Alarms the check expects per entry and target: a 95 % interval of about ±15 % (more with clustering).
ALARMS = 200


def delivered(settings: GaussianSettings, corr: gc.Correlation, h: float, detectors: int, cycles: int,
              seed: int) -> tuple[float, float, float, int]:
    """(delivered ARL0, its 95 % interval low and high, alarms) of ``detectors`` learned detectors
    with threshold ``h`` over ``cycles`` cycles each, every alarm acknowledged."""
    r = independent_learned_axes(np.asarray(corr, dtype=float), settings.learned_axes)
    rng = np.random.default_rng(seed)
    noise = gf.StreamNoise(np.asarray(np.linalg.cholesky(r), dtype=float), settings.wander, rng, settings.skew)
    samples = noise.sequence(detectors, settings.n0)                                  # plain learning sets
    learned = None if settings.transform == "none" else gf.LearnedTransforms.fit(samples[:, :, 0])
    nominal = gf.fit_nominals(samples) if learned is None else (learned.z_mean[:, None], learned.z_var[:, None, None])
    scale = np.ones((detectors, r.shape[0]))
    for axis in (0,) if settings.in_learned_units else settings.learned_axes:
        means, covs = nominal                      # the law is in learned units there: an exact fit, a spread drawn
        means[:, axis], covs[:, axis, :], covs[:, :, axis] = 0.0, 0.0, 0.0
        covs[:, axis, axis] = 1.0
        scale[:, axis] = np.maximum(settings.spread_mean[axis] + settings.spread_sd[axis]
                                    * rng.standard_normal(detectors), gf.MIN_SPREAD)
    glr = gf.fleet_detectors(settings, *nominal, 1)
    shift = gf.stream_shifts(settings, detectors, r.shape[0])[0]       # plain draws: every weight 1
    if settings.at == "healthy_drift":             # the check's own fleet drift, not the calibration's order
        shift = shift[rng.permutation(detectors)]
    noise.start(detectors)
    alarms = np.zeros(detectors)
    for _ in range(cycles):
        y = scale * noise.step(detectors) + shift
        alarm = glr.update(y if learned is None else learned.apply(y)) >= h
        if alarm.any():
            alarms += alarm
            glr.restart(alarm)
    total = float(alarms.sum())
    exposure = float(detectors * cycles)
    arl = exposure / max(total, 1.0)
    se_log = math.sqrt(max(float(np.var(alarms, ddof=1)) * detectors, 1.0)) / max(total, 1.0)   # clustered
    return arl, arl * math.exp(-1.96 * se_log), arl * math.exp(1.96 * se_log), int(total)


def check(entry: dict[str, Any], target: float, detectors: int, seed: int,
          learn_transform: bool = False) -> dict[str, Any] | None:
    """One entry at one target; ``learn_transform``: the simulated scalar detectors learn a Yeo–Johnson
    transform whatever the entry was calibrated for (what an entry without it delivers to the agent's steady
    detectors, which learn one)."""
    settings, corr = entry_settings(entry), entry_correlation(entry)
    found = lookup(settings, target, corr)
    if found is None:
        return None
    cycles = int(max(2000, ALARMS * target / detectors))          # ≈ ALARMS alarms if the target holds
    started = time.process_time()
    simulated = replace(settings, transform="yeo-johnson") if learn_transform and len(corr) == 1 else settings
    arl, low, high, alarms = delivered(simulated, corr, found.threshold, detectors, cycles, seed)
    row = {"settings": entry["settings"], "dim": len(corr), "rho": corr[1][2] if len(corr) > 1 else None,
           "target": target, "threshold": found.threshold, "h_se": found.h_se, "detectors": detectors,
           "cycles": cycles, "alarms": alarms, "delivered": arl, "low": low, "high": high,
           "ratio": arl / target, "cpu_s": time.process_time() - started}
    log.info("%s d=%d rho=%s target %.0f: h %.3f, delivered %.0f (%.0f … %.0f), ratio %.2f, %d alarms, %.0f s",
             settings.at, row["dim"], row["rho"], target, found.threshold, arl, low, high, arl / target, alarms,
             row["cpu_s"])
    return row


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--targets", default="1e3,1e4,1e5")
    parser.add_argument("--only", choices=("all", "scalar", "vector"), default="all")
    parser.add_argument("--detectors", type=int, default=16384,
                        help="learned detectors per entry and target (they learn from plain sets of values, so "
                             "the badly learned nominals that decide the warm-up's rate need many)")
    parser.add_argument("--stage", choices=("all", "warm-up", "steady"), default="all",
                        help="only the entries of the warm-up or of the steady nominal")
    parser.add_argument("--rho", type=float, default=None, help="only the joint vector's entry of this KL correlation")
    parser.add_argument("--transform", choices=("yeo-johnson", "none"), default=None,
                        help="only the entries of scalar detectors that learn this transform (steady) or none")
    parser.add_argument("--learn-transform", action="store_true",
                        help="scalar detectors learn a Yeo-Johnson transform even where the entry was calibrated "
                             "without one (what such an entry delivers to the agent's steady detectors)")
    parser.add_argument("--json", type=Path)
    args = parser.parse_args(argv)
    logging.basicConfig(level=logging.INFO, format="%(asctime)s %(name)s %(message)s")
    rows = []
    entries = [e for group in entries_by_key().values() for e in group]
    for k, e in enumerate(entries):
        dim = len(entry_correlation(e))
        if (args.only == "scalar" and dim > 1) or (args.only == "vector" and dim == 1):
            continue
        if not in_stage(entry_settings(e), args.stage):
            continue
        if args.rho is not None and (dim == 1 or abs(entry_correlation(e)[1][2] - args.rho) > 1e-9):
            continue
        if args.transform is not None and entry_settings(e).transform != args.transform:
            continue
        for target in (float(t) for t in args.targets.split(",")):
            row = check(e, target, args.detectors, CHECK_SEED + k, args.learn_transform)
            if row is not None:
                rows.append(row)
    print("| settings | d | ρ | target | h [nats] | delivered ARL0 (95 %) | delivered / target | alarms |")
    print("|---|---|---|---|---|---|---|---|")
    for r in rows:
        s = r["settings"]
        name = f"{s['at']}, N0 {s['n0']}" + (f", drift {s['drift_mean']} ± {s['drift_sd']}" if s["drift_mean"] else "") \
            + (f", wander {s['wander']}" if s.get("wander") else "") \
            + (f", {s['transform']}" if s.get("transform", "none") != "none" else "")
        print(f"| {name} | {r['dim']} | {'' if r['rho'] is None else r['rho']} | {r['target']:.0f} | "
              f"{r['threshold']:.3f} ± {r['h_se']:.3f} | {r['delivered']:.0f} ({r['low']:.0f} … {r['high']:.0f}) | "
              f"{r['ratio']:.2f} | {r['alarms']} |")
    if args.json:
        args.json.write_text(json.dumps(rows, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
