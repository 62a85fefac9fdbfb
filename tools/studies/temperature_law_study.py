#!/usr/bin/env python3
"""How a healthy joint's detector inputs drift with the temperature while it warms, and what the learned
temperature slack leaves of it (docs/DETECTION.md, "Watching while the joint warms").

Reads the per-cycle quantities studies.series keeps (computed there if missing). Per joint the warm-up nominal
is its first ``decision.n_nominal`` values, the span the smoothed motor temperature's over those cycles
(edge_monitor/pipeline/hold_temperature.py), d the smoothed temperature's distance outside it; over the warm-up
(the first ``--until`` rows) each input in standard deviations of its nominal is fitted by z = a·√d:

* the fleet's law: mean, sd and the largest a over joints, per input (the prior of ``[decision.temperature_slack]``);
* what the shipped detectors test, replayed over the same rows (studies.bank_replay): per joint the mean of a warm-up
  scalar detector's value less its slack over the cycles more than 5 °C out, in standard deviations of its
  nominal; mean, sd and the largest over joints (the drift ``[decision.healthy_drift]`` calibrates for);
* the spread of the same values: per joint their standard deviation about the joint's own mean, in standard
  deviations of the nominal;
* the warm-up law (``[decision.warm_up_law]``): the same mean and spread per joint over every cycle its warm-up
  detector tests, and their mean and sd over joints; and the shape of those values per joint (skewness, the share
  above 2 and above 2.5 of their sd, the variance ratios of 10- and 30-cycle means), averaged over joints;
* the correlation of the joints' warm-up means and spreads (the law draws them independently);
* the law's skew (its sixth number): the skew-normal shape whose values, with the law's wander, put the measured
  share above 2 sd (:func:`tail_shape`), and the share above 2.5 sd that shape predicts, a check of the fit.

Usage: ``python tools/studies/temperature_law_study.py --seeds 7001-7012 [--cycles 1000] [--scenario NAME] [--json OUT]``;
several groups pooled: ``--group 7001-7002 --group 401-407,7101-7104@plant_week:4400 --until 1200`` (seeds, then
``@scenario`` and ``:cycles`` if not the default's); ``--no-motor-temperature``: robots whose controller sends none; ``--set TABLE.KEY=VALUE``: replayed with that
agent setting.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
from pathlib import Path
from typing import Any

import numpy as np
from scipy.integrate import quad
from scipy.optimize import brentq
from scipy.stats import norm, skewnorm

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))

from edge_monitor.config import config_from_mapping  # noqa: E402
from edge_monitor.features.registry import QUANTITIES  # noqa: E402
from edge_monitor.pipeline.decision_config import DecisionConfig  # noqa: E402
from edge_monitor.pipeline.hold_temperature import HoldTemperature  # noqa: E402
from edge_monitor.stats.calibration import MAX_SKEW  # noqa: E402
from studies.bank_replay import detectors_temperature, new_bank, replay_bank  # noqa: E402
from studies.robots import kept_robot_pauses  # noqa: E402
from studies.series import robot_series  # noqa: E402
from studies.settings import parse_seeds, parse_set, settings_from  # noqa: E402

INPUTS = ("wear_score", "kl_raw", "kl_weighted")
SCALARS = ("wear", "kl_raw", "kl_weighted")
#: Only the cycles this far [°C] outside the span count for what the slack leaves.
OUT_BY = 5.0


def _watched(row: dict[str, Any], name: str) -> float:
    return math.log(row[name]) if name.startswith("kl") else float(row[name])


def law(rows: list[dict[str, Any]], n0: int, until: int) -> dict[str, float]:
    """Per input, a of z = a·√d over rows n0 … until (see the module docstring)."""
    smoothing = HoldTemperature()
    smoothed = np.array([np.nan if (t := smoothing.update(detectors_temperature(r)[0])) is None else t
                         for r in rows[:until]])
    lo, hi = np.nanmin(smoothed[:n0]), np.nanmax(smoothed[:n0])
    root = np.sqrt(np.maximum(0.0, np.maximum(smoothed - hi, lo - smoothed)))[n0:]
    out = {}
    for name in INPUTS:
        y = np.array([_watched(r, name) for r in rows[:until]])
        z = (y[n0:] - y[:n0].mean()) / y[:n0].std(ddof=1)
        ok = np.isfinite(root) & np.isfinite(z)
        out[name] = float(np.sum(root[ok] * z[ok]) / np.sum(root[ok] ** 2)) if np.any(root[ok] > 0) else math.nan
    return out


def tested_values(rows: list[dict[str, Any]], decision: DecisionConfig, until: int,
                  stops: dict[int, float] | None = None, out_by: float = OUT_BY) -> dict[str, np.ndarray]:
    """Per warm-up scalar detector, its tested values less its slack [σ of its nominal], in cycle order, over the
    cycles more than ``out_by`` °C out (−inf: every cycle it tests); ``stops``: the seconds the robot stood still
    before a cycle, seen as the agent sees them. An alarm is acknowledged (the statistic restarts)."""
    bank = new_bank(decision)
    left: dict[str, list[float]] = {q: [] for q in SCALARS}

    def before(row: dict[str, Any]) -> dict[str, Any]:
        for q in SCALARS:
            detector = bank.detectors[q]
            side, d = bank.spans.outside(q, detector, bank.smoothed)
            density = detector.density
            if detector.stage != "warm-up" or density is None or d <= out_by:
                continue
            slack = bank.spans.slack(q, QUANTITIES[q].inputs, detector, bank.smoothed)
            z = (_watched(row, QUANTITIES[q].inputs[0]) - density.mean[0]) / density.spread[0]
            left[q].append(z - (slack[0] if slack else 0.0))
        return row

    for step in replay_bank(bank, rows[:until], values=before, pauses=stops):
        for alarm in step.raised:
            bank.detectors[alarm.quantity].acknowledge()
    return {q: np.asarray(v) for q, v in left.items()}


def left_by_slack(rows: list[dict[str, Any]], decision: DecisionConfig, until: int,
                  stops: dict[int, float] | None = None, out_by: float = OUT_BY) -> dict[str, tuple[float, float]]:
    """Per warm-up scalar detector, the mean and the standard deviation of :func:`tested_values` (NaN with fewer
    than 30 of them)."""
    return {q: (float(np.mean(v)), float(np.std(v, ddof=1))) if len(v) >= 30 else (math.nan, math.nan)
            for q, v in tested_values(rows, decision, until, stops, out_by).items()}


def shape(values: np.ndarray) -> dict[str, float]:
    """Of one joint's tested values: their skewness, the share above 2 of their own standard deviations (a
    Gaussian's: 0.0228) and k·var(k-cycle mean)/var at k = 10 and 30 (independent values: 1); NaN with fewer
    than 120 values."""
    if values.size < 120:
        return dict.fromkeys(("skewness", "above_2sd", "above_2_5sd", "ratio_10", "ratio_30"), math.nan)
    u = (values - values.mean()) / values.std()
    ratios = {k: k * float(np.var(u[:u.size // k * k].reshape(-1, k).mean(axis=1))) for k in (10, 30)}
    return {"skewness": float(np.mean(u ** 3)), "above_2sd": float(np.mean(u > 2.0)),
            "above_2_5sd": float(np.mean(u > 2.5)), "ratio_10": ratios[10], "ratio_30": ratios[30]}


def share_above(alpha: float, wander: float, x: float) -> float:
    """P(v > x) of unit-variance values v = √(1 − f)·s + √f·w, s standardised skew-normal of shape ``alpha`` and w
    standard normal (the wander, variance fraction f = ``wander``): the calibration's values
    (edge_monitor.stats.gaussian_fleet.StreamNoise)."""
    mean, var = (float(m) for m in skewnorm.stats(alpha, moments="mv"))
    a, b = math.sqrt(1.0 - wander), math.sqrt(wander)
    if wander == 0.0:
        return float(skewnorm.sf(mean + math.sqrt(var) * x, alpha))
    return float(quad(lambda w: norm.pdf(w) * skewnorm.sf(mean + math.sqrt(var) * (x - b * w) / a, alpha), -9, 9)[0])


def tail_shape(above_2sd: float, wander: float) -> float:
    """The skew-normal shape α whose values (:func:`share_above`) put ``above_2sd`` above 2 sd; NaN if no α within
    the law's bound (±MAX_SKEW) does (a Gaussian: α = 0, 0.0228)."""
    low, high = (share_above(a, wander, 2.0) - above_2sd for a in (-MAX_SKEW, MAX_SKEW))
    if not (math.isfinite(above_2sd) and low <= 0.0 <= high):
        return math.nan
    return float(brentq(lambda a: share_above(a, wander, 2.0) - above_2sd, -MAX_SKEW, MAX_SKEW, xtol=1e-4))


def tail_fits(above_2sd: dict[str, dict[str, float]], decision: DecisionConfig) -> dict[str, dict[str, float]]:
    """Per scalar input: :func:`tail_shape` of its joints' mean share above 2 sd, with the wander of its shipped
    warm-up law, and the share above 2.5 sd that shape predicts."""
    out = {}
    for q, found in above_2sd.items():
        law = decision.warm_up_law.get(QUANTITIES[q].inputs[0], ())
        wander = law[4] if law else 0.0
        alpha = tail_shape(found.get("mean", math.nan), wander)
        out[q] = {"alpha": alpha, "wander": wander,
                  "above_2_5sd": share_above(alpha, wander, 2.5) if math.isfinite(alpha) else math.nan}
    return out


def _summary(values: list[float]) -> dict[str, float]:
    v = np.array([x for x in values if math.isfinite(x)])
    return {"joints": int(v.size), "mean": float(v.mean()), "sd": float(v.std(ddof=1)), "max": float(v.max()),
            "min": float(v.min())} if v.size > 1 else {"joints": int(v.size)}


def _correlation(a: list[float], b: list[float]) -> float:
    """Pearson correlation over the joints where both are measured (NaN below 3 joints)."""
    x, y = np.asarray(a, float), np.asarray(b, float)
    ok = np.isfinite(x) & np.isfinite(y)
    return float(np.corrcoef(x[ok], y[ok])[0, 1]) if ok.sum() >= 3 else math.nan


def _group(text: str, cycles: int) -> tuple[str, str | None, int]:
    """``SEEDS[@SCENARIO][:CYCLES]`` → (seeds, scenario, cycles)."""
    seeds, _, rest = text.partition("@")
    if ":" in (rest or seeds):
        head, _, count = (rest or seeds).rpartition(":")
        cycles = int(count)
        seeds, rest = (seeds, head) if rest else (head, "")
    return seeds, rest or None, cycles


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--seeds", default=None)
    parser.add_argument("--group", action="append", default=[],
                        help="SEEDS[@SCENARIO][:CYCLES], pooled with --seeds and other groups (repeatable)")
    parser.add_argument("--cycles", type=int, default=1000)
    parser.add_argument("--until", type=int, default=700, help="rows of the warm-up per joint (default 700)")
    parser.add_argument("--scenario", default=None, help="simulator scenario of the kept series (e.g. plant_week)")
    parser.add_argument("--no-motor-temperature", action="store_true",
                        help="robots whose controller sends none (their detectors follow the friction's temperature)")
    parser.add_argument("--set", action="append", default=[], type=parse_set, metavar="TABLE.KEY=VALUE",
                        help="agent setting (TOML value) the detectors are replayed with, e.g. "
                             "decision.learned_sd_prior_friction='{\"wear_score\": [60, 1.0]}'")
    parser.add_argument("--json", type=Path)
    args = parser.parse_args(argv)
    groups = [_group(g, args.cycles) for g in args.group]
    if args.seeds:
        groups.insert(0, (args.seeds, args.scenario, args.cycles))
    if not groups:
        parser.error("give --seeds or --group")
    decision = config_from_mapping(settings_from(tuple(args.set))).decision
    laws: dict[str, list[float]] = {name: [] for name in INPUTS}
    parts = ("left_by_slack", "spread", "warm_up_mean", "warm_up_spread", "skewness", "above_2sd", "above_2_5sd",
             "ratio_10", "ratio_30")
    found: dict[str, dict[str, list[float]]] = {part: {q: [] for q in SCALARS} for part in parts}
    for seeds, scenario, cycles in groups:
        for seed in parse_seeds(seeds):
            stops = kept_robot_pauses(seed, cycles, scenario)
            for _, rows in sorted(robot_series(seed, cycles, scenario=scenario,
                                                             motor_temperature=not args.no_motor_temperature).items()):
                for name, a in law(rows, decision.n_nominal, args.until).items():
                    laws[name].append(a)
                for q, (mean, sd) in left_by_slack(rows, decision, args.until, stops).items():
                    found["left_by_slack"][q].append(mean)
                    found["spread"][q].append(sd)
                for q, values in tested_values(rows, decision, args.until, stops, -math.inf).items():
                    found["warm_up_mean"][q].append(float(np.mean(values)) if values.size >= 30 else math.nan)
                    found["warm_up_spread"][q].append(float(np.std(values, ddof=1)) if values.size >= 30 else math.nan)
                    for part, value in shape(values).items():
                        found[part][q].append(value)
    out = {"law": {k: _summary(v) for k, v in laws.items()},
           **{part: {k: _summary(v) for k, v in found[part].items()} for part in parts}}
    for part, table in out.items():
        for name, s in table.items():
            if "mean" in s:
                print(f"{part:>14} {name:>12}: {s['mean']:+.3f} ± {s['sd']:.3f} (min {s['min']:+.3f}, "
                      f"max {s['max']:+.3f}) over {s['joints']} joints")
    out["mean_spread_correlation"] = {q: {"r": _correlation(found["warm_up_mean"][q], found["warm_up_spread"][q])}
                                      for q in SCALARS}
    for name, c in out["mean_spread_correlation"].items():
        print(f"    mean–spread {name:>12}: correlation of the joints' warm-up means and spreads {c['r']:+.3f}")
    out["tail_shape"] = tail_fits(out["above_2sd"], decision)
    for name, fit in out["tail_shape"].items():
        print(f"    tail_shape {name:>12}: skew-normal shape {fit['alpha']:+.2f} (share above 2.5 sd predicted "
              f"{fit['above_2_5sd']:.4f}, measured {out['above_2_5sd'][name].get('mean', math.nan):.4f})")
    if args.json:
        args.json.write_text(json.dumps(out, indent=1) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
