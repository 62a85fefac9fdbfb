#!/usr/bin/env python3
"""How well the lubricant thermal filter tracks a joint whose controller sends no motor temperature
(docs/WITHOUT_MOTOR_TEMPERATURE.md).

Runs simulated default robots (6 joints, individual variation, the thermal model, the load spread) through the
agent's features with every motor temperature removed and its detectors off. Per joint and cycle it keeps the
friction-read lubricant temperature ξ̂ (the wear feature's), the cycle's power ⟨τ·v⟩, its controller times and
the simulator's true lubricant temperature. Then it replays, per joint, the shipped
:class:`~edge_monitor.features.lubricant_thermal_filter.LubricantThermalFilter` and the exponential smoothing it
replaced (weight 0.1, cooled through each stop towards the coldest value it had shown). It prints each one's error against the truth after the first ``--skip`` cycles: rms and
worst, with the joint's mean offset over those cycles removed (the friction model's temperature scale is the
joint's own), and the reading's scale: the slope of ξ̂ against the true temperature [°C per °C] (1: none compressed).
``--variation`` sets the simulator's individual variation (0: identical joints), ``--base-model`` keeps the agent on
the base friction table (no per-joint model learning: on identical joints the exact model), ``--wear`` wears every
joint to that level from the start.

Usage: ``python tools/studies/thermal_filter_study.py --seeds 7001-7002 [--cycles 1000] [--scenario plant_week]
[--set ambient_drift=2] [--variation 0] [--base-model] [--wear 20] [--rows ROWS.json] [--json OUT]`` (≈ 100 s per 1 000 cycles of a robot; ``--rows`` keeps
them, so other filter settings replay in seconds).
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

from edge_monitor.config import config_from_mapping  # noqa: E402
from edge_monitor.features.lubricant_thermal_filter import (  # noqa: E402
    LubricantThermalFilter,
    ThermalFilterConfig,
    ThermalObservation,
)
from edge_monitor.offline.fast_path import CycleFeeder  # noqa: E402
from edge_monitor.pipeline.agent import Agent  # noqa: E402
from edge_monitor.pipeline.pauses import PAUSE_S  # noqa: E402
from sim_controller.cycle_mode import (
    cycle_signals,  # noqa: E402
    without_motor_temperature,  # noqa: E402
)
from sim_controller.scenario import scenario_config  # noqa: E402
from studies.settings import parse_seeds  # noqa: E402

log = logging.getLogger("thermal_filter_study")
SMOOTHING = 0.1


def robot_rows(seed: int, cycles: int | None, scenario: str | None = None, variation: float | None = None,
               base_model: bool = False, wear: float = 0.0) -> dict[int, list[dict[str, float]]]:
    """Per joint, per cycle with a friction reading: ξ̂, power, controller times and the true temperature."""
    overrides: dict[str, Any] = {"seed": seed, "joints": 6}
    if cycles is not None:
        overrides["cycles"] = cycles
    if variation is not None:
        overrides["variation"] = variation
    worn = tuple(f"{joint}:0:1:{wear:g}:{wear:g}" for joint in range(6)) if wear else ()
    config = scenario_config(scenario, overrides, wear_ramps=worn)
    cycles = config.cycles
    agent = Agent(config_from_mapping({"decision": {"enabled": False}, "model": {"enabled": not base_model}}))
    feeder = CycleFeeder(agent)
    pending: dict[tuple[int, int], dict[str, float]] = {}
    rows: dict[int, list[dict[str, float]]] = {}

    def take(symptoms: list[Any]) -> None:
        for s in symptoms:
            reading = (s.to_dict().get("wear") or {}).get("temperature")
            row = pending.pop((s.cycle, s.joint), None)
            if row is not None and isinstance(reading, (int, float)) and math.isfinite(reading):
                rows.setdefault(s.joint, []).append({**row, "reading": float(reading)})

    for sig in cycle_signals(config):
        for js, truth in zip(sig.joints, sig.truth):
            pending[(sig.cycle, js.joint)] = {"power": float(np.mean(js.torque * js.speed)),
                                              "t_start": truth["t_start"], "t_end": truth["t_end"],
                                              "truth": truth["temperature"]}
        take(feeder.update(without_motor_temperature(sig)))
        if sig.cycle % 200 == 0:
            log.info("seed %d: cycle %d/%d", seed, sig.cycle, cycles)
    take(feeder.finish())
    return rows


def replay(rows: list[dict[str, float]], config: ThermalFilterConfig | None = None) -> dict[str, np.ndarray]:
    """The filter's and the smoothing's temperature after each row."""
    f = LubricantThermalFilter(config)
    smoothed, coldest, out_f, out_s = None, math.inf, [], []
    for k, row in enumerate(rows):
        gap = row["t_start"] - rows[k - 1]["t_end"] if k else 0.0
        run = row["t_end"] - row["t_start"] + (gap if gap < PAUSE_S else 0.0)
        if gap >= PAUSE_S:
            f.cool(gap)
            if smoothed is not None:      # the former compensation cooled towards the coldest value it had shown
                smoothed = coldest + (smoothed - coldest) * math.exp(-gap / f.config.time_constant_s)
        out_f.append(f.update(ThermalObservation(run, row["power"], row["reading"])))
        smoothed = row["reading"] if smoothed is None else smoothed + SMOOTHING * (row["reading"] - smoothed)
        coldest = min(coldest, smoothed)
        out_s.append(smoothed)
    return {"filter": np.asarray(out_f, dtype=float), "smoothing": np.asarray(out_s, dtype=float),
            "reading": np.asarray([r["reading"] for r in rows])}


def errors(rows: list[dict[str, float]], skip: int, config: ThermalFilterConfig | None = None
           ) -> dict[str, dict[str, float]]:
    truth = np.asarray([r["truth"] for r in rows])
    out = {}
    estimates = replay(rows, config)
    for name, est in estimates.items():
        err = (est - truth)[skip:]
        err = err - np.mean(err)
        out[name] = {"rms": float(np.sqrt(np.mean(err ** 2))), "worst": float(np.max(np.abs(err)))}
    out["reading"]["scale"] = float(np.polyfit(truth[skip:], estimates["reading"][skip:], 1)[0])
    return out


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--seeds", default="7001-7002")
    p.add_argument("--cycles", type=int, help="cycles per robot (default: 1000, or the scenario's)")
    p.add_argument("--scenario", help="simulator scenario: a TOML file or a packaged name (e.g. plant_week)")
    p.add_argument("--set", action="append", default=[], metavar="FIELD=VALUE",
                   help="a filter setting (ThermalFilterConfig), e.g. ambient_drift=2")
    p.add_argument("--variation", type=float, help="the simulator's individual variation (default: its own)")
    p.add_argument("--base-model", action="store_true", help="the agent on the base friction table (no model learning)")
    p.add_argument("--wear", type=float, default=0.0, help="every joint worn to this level from the start")
    p.add_argument("--rows", type=Path, help="keep the robots' rows here, and read them from here when present")
    p.add_argument("--skip", type=int, default=80, help="cycles left out at the start (the filter learning)")
    p.add_argument("--json", type=Path)
    a = p.parse_args(argv)
    logging.basicConfig(level=logging.INFO, format="%(asctime)s %(message)s", datefmt="%H:%M:%S")
    logging.getLogger("edge_monitor").setLevel(logging.WARNING)
    config = ThermalFilterConfig(**{k: float(v) for k, v in (item.split("=", 1) for item in a.set)})
    cycles = a.cycles if a.cycles is not None or a.scenario else 1000
    kept = json.loads(a.rows.read_text()) if a.rows and a.rows.exists() else {}
    result: list[dict[str, Any]] = []
    variant = ("" if a.variation is None else f":variation={a.variation:g}") + (":base" if a.base_model else "") \
        + (f":wear={a.wear:g}" if a.wear else "")
    for seed in parse_seeds(a.seeds):
        key = f"{seed}{variant}"
        if key not in kept:
            rows_by_joint = robot_rows(seed, cycles, a.scenario, a.variation, a.base_model, a.wear)
            kept[key] = {str(j): r for j, r in rows_by_joint.items()}
            if a.rows:
                a.rows.write_text(json.dumps(kept))
        for joint, rows in sorted((int(j), r) for j, r in kept[key].items()):
            if len(rows) <= a.skip:
                continue
            e = errors(rows, a.skip, config)
            result.append({"seed": seed, "joint": joint, **e})
            print(f"{seed} j{joint}: rms / worst [°C]  reading {e['reading']['rms']:.2f} / {e['reading']['worst']:.1f}"
                  f"   smoothing {e['smoothing']['rms']:.2f} / {e['smoothing']['worst']:.1f}"
                  f"   filter {e['filter']['rms']:.2f} / {e['filter']['worst']:.1f}"
                  f"   reading scale {e['reading']['scale']:.3f}", flush=True)
    for name in ("reading", "smoothing", "filter"):
        rms = [r[name]["rms"] for r in result]
        worst = [r[name]["worst"] for r in result]
        print(f"{name:9s}: rms {min(rms):.2f}–{max(rms):.2f} °C, worst {min(worst):.1f}–{max(worst):.1f} °C "
              f"over {len(result)} joints")
    scales = [r["reading"]["scale"] for r in result]
    print(f"reading scale: {min(scales):.3f}–{max(scales):.3f} °C per °C")
    if a.json:
        a.json.write_text(json.dumps(result, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
