#!/usr/bin/env python3
"""Warm-up drift study: how far each monitored quantity of a HEALTHY joint moves from what its detector
learned while the lubricant warms beyond the learning range.

Part ``drift`` (default): the agent on the simulator's fast path (edge_monitor.offline.fast_path) at
the simulator's defaults (6 joints, ±8 % individual variation, the lubricant warming from 30 °C towards
its steady state, load spread), detectors off. For every joint and quantity the detector's nominal is
its first ``decision.n_nominal`` values in the units it watches (log for the KL distances); every later
window of ``--window`` cycles is reported as

* shift  = (window mean − learned mean) / learned std  [σ]
* spread = window std / learned std

with the window's mean true lubricant temperature [°C]. A stationary quantity keeps shift ≈ 0 and
spread ≈ 1; the detectors' drift allowance is 0.75 σ (docs/DETECTION.md). ``--set kl.min_speed=1``
reproduces the former KL sample selection. Then, per quantity, how each joint's late shift (mean of
the windows after the first) goes with its individual friction parameters (``causes``).

Part ``residual``: where the KL temperature compensation is inexact. One joint (no individual
variation, fixed load) simulates the same cycle, with the same noise, at two lubricant temperatures;
the warm cycle's torque is moved to the cold temperature by the agent's TemperatureCompensation with the
exact friction model and the true temperatures, and the residual against the cold cycle is
reported per speed band (rms, torque as a fraction of the joint's maximum). Whatever remains is not
static friction: the speed loop's response to the temperature-dependent Stribeck friction.

Part ``variant``: what sets one joint's late drift. The joint (``--joint``, first of ``--seeds``) runs
with its friction as drawn, as the base table, or with one parameter drawn and the rest base
(``--variants``), the other joints as drawn; with ``--set`` the agent's settings change too (e.g.
``model.max_relative_std=1e-4`` keeps every parameter at its base value instead of identifying it).
Prints the joint's mean shift over its windows from the third on.

Usage: .venv/bin/python tools/studies/warmup_drift_study.py [--seeds 1 2] [--cycles 600] [--set kl.min_speed=1]
       .venv/bin/python tools/studies/warmup_drift_study.py --part variant --seeds 7 --joint 2 --variants drawn,base
       .venv/bin/python tools/studies/warmup_drift_study.py --part residual
"""

from __future__ import annotations

import argparse
import json
import logging
import sys
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))

from edge_monitor.features.registry import LOG_SCALE  # noqa: E402
from edge_monitor.features.temperature_compensation import TemperatureCompensation  # noqa: E402
from edge_monitor.offline.fast_path import DETECTOR_INPUTS, detector_inputs_with_truth  # noqa: E402
from edge_monitor.pipeline.detectors import DEFAULT_NOMINAL  # noqa: E402
from joint_model import FrictionParams  # noqa: E402
from sim_controller.config import JointOverride, SimConfig  # noqa: E402
from sim_controller.controller import VARIED_PARAMS, Controller  # noqa: E402
from sim_controller.cycle_mode import cycle_signals  # noqa: E402
from sim_controller.scenario import scenario_config  # noqa: E402
from studies.settings import parse_set, settings_from  # noqa: E402

log = logging.getLogger("warmup_drift_study")

#: Speed bands of the residual part [rad/s].
SPEED_BANDS = ((1.0, 5.0), (5.0, 10.0), (10.0, 50.0), (50.0, 120.0), (120.0, 200.0), (200.0, 300.0))


def joint_series(config: SimConfig, settings: dict[str, Any]) -> dict[int, dict[str, np.ndarray]]:
    """Per joint: cycle, true lubricant temperature [°C] and each detector input in watched units."""
    rows: dict[int, list[tuple[float, ...]]] = {}
    for joint, cycle, values, truth in detector_inputs_with_truth(config, settings):
        watched = [np.log(values[q]) if q in LOG_SCALE else values[q] for q in DETECTOR_INPUTS]
        rows.setdefault(joint, []).append((cycle, float(truth.get("temperature", np.nan)), *watched))
        if joint == 0 and cycle % 100 == 99:
            log.info("seed %d: cycle %d/%d", config.seed, cycle + 1, config.cycles)
    out = {}
    for joint, data in rows.items():
        table = np.asarray(data, dtype=float)
        out[joint] = {"cycle": table[:, 0], "temperature": table[:, 1],
                      **{q: table[:, 2 + i] for i, q in enumerate(DETECTOR_INPUTS)}}
    return out


def drift_rows(series: dict[str, np.ndarray], window: int, n_nominal: int = DEFAULT_NOMINAL) -> list[dict[str, Any]]:
    """Shift and spread of every later window of one joint, per quantity (see the module docstring)."""
    learn = slice(0, n_nominal)
    temperature = series["temperature"]
    rows = []
    for start in range(n_nominal, len(temperature) - window // 2, window):
        part = slice(start, start + window)
        row: dict[str, Any] = {"first_cycle": int(series["cycle"][start]),
                               "temperature": round(float(np.nanmean(temperature[part])), 1),
                               "learned_temperature": [round(float(np.nanmin(temperature[learn])), 1),
                                                       round(float(np.nanmax(temperature[learn])), 1)]}
        for q in DETECTOR_INPUTS:
            mu, sd = float(np.nanmean(series[q][learn])), float(np.nanstd(series[q][learn], ddof=1))
            values = series[q][part]
            row[q] = {"shift": round((float(np.nanmean(values)) - mu) / sd, 2),
                      "spread": round(float(np.nanstd(values, ddof=1)) / sd, 2)}
        rows.append(row)
    return rows


def drift(seeds: list[int], cycles: int, joints: int, window: int, settings: dict[str, Any],
          scenario: str | None = None) -> dict[str, Any]:
    """The drift part on each seed (the simulator's defaults, or ``scenario``: a file or packaged name)."""
    joints_out = []
    for seed in seeds:
        config = scenario_config(scenario, {"joints": joints, "cycles": cycles, "seed": seed})
        variation = joint_variation(config)
        for joint, series in sorted(joint_series(config, settings).items()):
            joints_out.append({"seed": seed, "joint": joint, "variation": variation[joint],
                               "windows": drift_rows(series, window)})
    return {"seeds": seeds, "cycles": cycles, "joints": joints, "window": window, "settings": settings,
            "scenario": scenario,
            "per_joint": joints_out, "summary": summarise(joints_out), "causes": causes(joints_out)}


def joint_variation(config: SimConfig) -> list[dict[str, float]]:
    """Per joint, each individually varied friction parameter relative to the base table (0.05 = +5 %)."""
    base = config.friction
    return [{name: round(getattr(setup.friction, name) / getattr(base, name) - 1.0, 4) for name in VARIED_PARAMS}
            for setup in Controller(config).joints]


def causes(per_joint: list[dict[str, Any]]) -> dict[str, dict[str, Any]]:
    """Per quantity: how each joint's late shift (mean over all windows after the first) goes with its
    individual parameters — the correlation with each, and the R² of a fit on fsξ and fvξ alone."""
    out: dict[str, dict[str, Any]] = {}
    params = np.array([[j["variation"][n] for n in VARIED_PARAMS] for j in per_joint])
    for q in DETECTOR_INPUTS:
        late = np.array([np.mean([w[q]["shift"] for w in j["windows"][1:] or j["windows"]]) for j in per_joint])
        design = np.column_stack([np.ones(len(late)), params[:, VARIED_PARAMS.index("fsxi")],
                                  params[:, VARIED_PARAMS.index("fvxi")]])
        fitted = design @ np.linalg.lstsq(design, late, rcond=None)[0]
        total = float(np.sum((late - late.mean()) ** 2))
        if total == 0:                         # nothing moves: nothing to explain
            out[q] = {"corr": dict.fromkeys(VARIED_PARAMS), "r2_temperature_coefficients": None}
            continue
        out[q] = {"corr": {n: round(float(np.corrcoef(params[:, i], late)[0, 1]), 2)
                           for i, n in enumerate(VARIED_PARAMS)},
                  "r2_temperature_coefficients": round(1.0 - float(np.sum((late - fitted) ** 2)) / total, 2)}
    return out


def summarise(per_joint: list[dict[str, Any]]) -> list[dict[str, Any]]:
    """Per window position: over all joints, the median and largest shift and the median spread."""
    out = []
    for k in range(min(len(j["windows"]) for j in per_joint)):
        windows = [j["windows"][k] for j in per_joint]
        row: dict[str, Any] = {"first_cycle": windows[0]["first_cycle"],
                               "temperature": round(float(np.mean([w["temperature"] for w in windows])), 1)}
        for q in DETECTOR_INPUTS:
            shifts = np.array([w[q]["shift"] for w in windows])
            row[q] = {"median_shift": round(float(np.median(shifts)), 2), "max_shift": round(float(shifts.max()), 2),
                      "min_shift": round(float(shifts.min()), 2),
                      "median_spread": round(float(np.median([w[q]["spread"] for w in windows])), 2)}
        out.append(row)
    return out


def variant_friction(config: SimConfig, joint: int, variant: str) -> FrictionParams:
    """The friction of ``joint`` for one variant: ``drawn`` (its individual parameters), ``base`` (the
    base table), a parameter name (the base table with only that one drawn), ``all_but_<name>`` (drawn
    with that one at its base value)."""
    drawn, base = Controller(config).joints[joint].friction, config.friction
    if variant in ("drawn", "base"):
        return drawn if variant == "drawn" else base
    name = variant.removeprefix("all_but_")
    if name not in VARIED_PARAMS:
        raise ValueError(f"variant {variant!r}: use drawn, base, one of {VARIED_PARAMS} or all_but_<one of them>")
    if variant.startswith("all_but_"):
        return replace(drawn, **{name: getattr(base, name)})
    return replace(base, **{name: getattr(drawn, name)})


def variant_drift(seed: int, joint: int, joints: int, cycles: int, variant: str, settings: dict[str, Any],
                  window: int = 150) -> dict[str, Any]:
    """One joint's late shift (mean of its windows from the third on) with its friction set by
    :func:`variant_friction`, the other joints as drawn."""
    config = SimConfig(joints=joints, seed=seed, cycles=cycles)
    friction = variant_friction(config, joint, variant)
    config = replace(config, joint_overrides=tuple(JointOverride(friction=friction) if j == joint else None
                                                   for j in range(joints)))
    windows = drift_rows(joint_series(config, settings)[joint], window)
    late = windows[2:] or windows
    return {"variant": variant, "temperature": late[-1]["temperature"],
            **{q: round(float(np.mean([w[q]["shift"] for w in late])), 2) for q in DETECTOR_INPUTS}}


def markdown(result: dict[str, Any]) -> str:
    lines = ["| from cycle | lubricant [°C] | " + " | ".join(f"{q}: shift median (min … max) / spread"
                                                            for q in DETECTOR_INPUTS) + " |",
             "|---|---|" + "---|" * len(DETECTOR_INPUTS)]
    for row in result["summary"]:
        cells = [f"{row[q]['median_shift']:+.2f} ({row[q]['min_shift']:+.2f} … {row[q]['max_shift']:+.2f}) / "
                 f"{row[q]['median_spread']:.2f}" for q in DETECTOR_INPUTS]
        lines.append(f"| {row['first_cycle']} | {row['temperature']:.1f} | " + " | ".join(cells) + " |")
    return "\n".join(lines)


def residual(cold: float = 35.0, warm: float = 55.0, seed: int = 5, load: float = 0.5) -> list[dict[str, float]]:
    """Rms compensation residual per speed band (see the module docstring)."""
    def one_cycle(temperature: float) -> tuple[np.ndarray, np.ndarray]:
        config = SimConfig(joints=1, cycles=1, seed=seed, variation=0.0, temperature_range=(temperature, temperature),
                           load_range=(load, load))
        signals = next(iter(cycle_signals(config))).joints[0]
        return signals.torque, signals.speed

    (tau_cold, v_cold), (tau_warm, v_warm) = one_cycle(cold), one_cycle(warm)
    compensation = TemperatureCompensation(FrictionParams(), smoothing=1.0)
    compensation.observe(cold)                       # the reference: where the nominal was learned
    compensation.observe(warm)                       # the current temperature, taken as is
    moved = compensation.apply(tau_warm, v_warm)
    rows = []
    for lo, hi in SPEED_BANDS:
        band = (np.abs(v_cold) >= lo) & (np.abs(v_cold) < hi)
        if band.any():
            rows.append({"speed_from": lo, "speed_to": hi, "samples": int(band.sum()),
                         "uncompensated_rms": float(np.sqrt(np.mean((tau_warm - tau_cold)[band] ** 2))),
                         "residual_rms": float(np.sqrt(np.mean((moved - tau_cold)[band] ** 2)))})
    return rows


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--part", choices=("drift", "residual", "variant"), default="drift")
    ap.add_argument("--joint", type=int, default=2, help="variant part: the joint whose friction is varied")
    ap.add_argument("--variants", default="drawn,base", help="variant part: drawn, base, a parameter name "
                    "(only that one drawn) or all_but_<name>, comma-separated")
    ap.add_argument("--seeds", type=int, nargs="+", default=[1])
    ap.add_argument("--cycles", type=int, default=600)
    ap.add_argument("--joints", type=int, default=6)
    ap.add_argument("--window", type=int, default=150, help="cycles per reported window")
    ap.add_argument("--scenario", metavar="FILE.toml|NAME", default=None,
                    help="drift part: simulator scenario of every seed (e.g. plant_week; joints and cycles as given)")
    ap.add_argument("--set", action="append", default=[], type=parse_set, metavar="TABLE.KEY=VALUE",
                    help="agent setting (value as JSON), e.g. kl.min_speed=1")
    ap.add_argument("--json", type=Path, default=None)
    args = ap.parse_args(argv)
    logging.basicConfig(level=logging.INFO, format="%(asctime)s %(message)s", datefmt="%H:%M:%S")
    for name in ("edge_monitor", "sim_controller"):
        logging.getLogger(name).setLevel(logging.WARNING)
    result: dict[str, Any]
    if args.part == "variant":
        settings = settings_from(tuple(args.set))
        result = {"seed": args.seeds[0], "joint": args.joint, "cycles": args.cycles, "settings": settings,
                  "variants": [variant_drift(args.seeds[0], args.joint, args.joints, args.cycles, v, settings)
                               for v in args.variants.split(",")]}
        print("| variant | late lubricant [°C] | " + " | ".join(DETECTOR_INPUTS) + " |\n|---|---|"
              + "---|" * len(DETECTOR_INPUTS))
        for r in result["variants"]:
            print(f"| {r['variant']} | {r['temperature']:.1f} | " + " | ".join(f"{r[q]:+.2f}" for q in DETECTOR_INPUTS)
                  + " |")
    elif args.part == "residual":
        result = {"residual": residual()}
        print("| speed band [rad/s] | samples | uncompensated rms | residual rms |\n|---|---|---|---|")
        for r in result["residual"]:
            print(f"| {r['speed_from']:g} … {r['speed_to']:g} | {r['samples']} | {r['uncompensated_rms']:.5f} | "
                  f"{r['residual_rms']:.5f} |")
    else:
        try:
            scenario_config(args.scenario, {"joints": args.joints, "cycles": args.cycles})
        except ValueError as exc:          # ScenarioError / SimConfigError: names the field
            ap.error(str(exc))
        result = drift(args.seeds, args.cycles, args.joints, args.window, settings_from(tuple(args.set)),
                       args.scenario)
        print(markdown(result))
        print("\n| quantity | R² on fsξ, fvξ | correlation of the late shift with each varied parameter |\n|---|---|---|")
        for q, c in result["causes"].items():
            print(f"| {q} | {c['r2_temperature_coefficients']} | "
                  + ", ".join(f"{n} {v:+.2f}" for n, v in c["corr"].items() if v is not None) + " |")
    if args.json:
        args.json.write_text(json.dumps(result, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
