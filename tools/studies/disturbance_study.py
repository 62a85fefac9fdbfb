#!/usr/bin/env python3
"""Disturbance study: what moves the agent's per-cycle quantities on a HEALTHY joint.

One disturbance at a time (temperature, load, individual friction-parameter variation), the others
off, everything else at simulator defaults; then the full default. For each run the simulator
records a log and ground truth (``sim-controller record``), the agent replays it
(``edge-monitor replay --jsonl``), and this script reads the symptom records and the truth.

Sub-commands (all write under ``--out``, default ``/tmp/dstudy``; ``nice`` is used for the heavy
processes, one at a time):

* ``run [NAME …]``   record + replay the scenarios of :data:`SCENARIOS` (skips finished ones);
  ``list`` shows them with their exact command lines.
* ``analyse``        tables (markdown, to ``--table-out``) and PNG plots (``--plot-dir``; needs
  matplotlib) from the finished runs.
* ``biasmap``        offline, noise-free (and noisy) wear-estimate bias of random ±8 % joints vs
  lubricant temperature, with the default and with each joint's own friction parameters.
* ``segments NAME``  offline attribution of the KL distances to parts of the cycle (each speed
  level, production motion, pauses) by re-running the agent's ``KLMonitor`` on subsets of the
  decoded samples of a recorded run.

Units: temperature °C, load and torque fractions of max. joint torque, wear 0 … 100, KL
dimensionless (the detectors watch log KL). "σ" is a quantity's own standard deviation (defined
in the table headers).

Usage: .venv/bin/python tools/studies/disturbance_study.py run; … analyse; … biasmap; … segments temp_wide
"""

from __future__ import annotations

import argparse
import json
import math
import os
import shutil
import subprocess
import sys
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any, Iterable

import numpy as np

ROOT = Path(__file__).resolve().parents[2]
BIN = ROOT / ".venv" / "bin"
SEED = 1
QUANTITIES = ("wear", "kl_raw", "kl_weighted")
#: GLR learning length and the cycles at which the drift is reported.
N_NOMINAL = 60
REPORT_AT = (100, 150, 200)
REPORT_WINDOW = 20


@dataclass(frozen=True)
class Scenario:
    """One run: simulator options (``--seed``/``--out``/``--truth`` added), or a replay of another
    scenario's log (``log_of``) with a per-joint friction config (``correct_params``)."""

    what: str
    sim: tuple[str, ...] = ()
    log_of: str | None = None
    correct_params: bool = False
    keep_log: bool = False
    external: bool = False     # lives in --default-dir (seed 0); recorded there only if missing


def _fixed(t: float) -> tuple[str, ...]:
    return ("--temperature-range", f"{t:g}:{t:g}")


LOAD_FIXED = ("--load-range", "0.5:0.5")
TEMPS = (30, 40, 50, 60, 70)

SCENARIOS: dict[str, Scenario] = {
    "base": Scenario("reference, no disturbance: vary 0, T 40 °C, load 0.5",
                     ("--joints", "2", "--cycles", "200", "--vary", "0", *_fixed(40), *LOAD_FIXED), keep_log=True),
    "temp_drift": Scenario("(a) temperature alone, default thermal drift: vary 0, load 0.5",
                           ("--joints", "2", "--cycles", "200", "--vary", "0", *LOAD_FIXED)),
    "temp_wide": Scenario("(a) temperature alone, wide drift 30 → 70 °C: vary 0, load 0.5, "
                          "thermal model with ambient 100 °C, no self-heating, time ×1.4",
                          ("--joints", "2", "--cycles", "200", "--vary", "0", *LOAD_FIXED,
                           "--ambient", "100", "--heating", "0", "--time-acceleration", "1.4"), keep_log=True),
    **{f"temp_fixed_{t}": Scenario(f"(a) temperature alone, fixed {t} °C: vary 0, load 0.5",
                                   ("--joints", "2", "--cycles", "60", "--vary", "0", *_fixed(t), *LOAD_FIXED))
       for t in TEMPS},
    "load": Scenario("(b) load alone: vary 0, T 40 °C, |τl| ~ U(0.3, 0.7)",
                     ("--joints", "2", "--cycles", "200", "--vary", "0", *_fixed(40)), keep_log=True),
    "vary": Scenario("(c) individual variation alone: vary 0.08, T 40 °C, load 0.5",
                     ("--joints", "6", "--cycles", "200", "--vary", "0.08", *_fixed(40), *LOAD_FIXED)),
    **{f"vary_fixed_{t}": Scenario(f"(1) vary 0.08, fixed {t} °C, load 0.5 (same joints as 'vary')",
                                   ("--joints", "6", "--cycles", "30", "--vary", "0.08", *_fixed(t), *LOAD_FIXED),
                                   keep_log=True)
       for t in TEMPS},
    **{f"vary_fixed_{t}_own": Scenario(f"(3) replay of vary_fixed_{t} with each joint's own friction parameters",
                                       log_of=f"vary_fixed_{t}", correct_params=True)
       for t in TEMPS},
    "default": Scenario("(d) full default: 6 joints, vary 0.08, thermal drift, load U(0.3, 0.7) "
                        "(the brief's run, seed 0)", ("--cycles", "200"), external=True),
    "default_own": Scenario("(3) replay of the full default with each joint's own friction parameters",
                            log_of="default", correct_params=True),
}


# ------------------------------------------------------------------------------------------------ running

def scenario_dir(out: Path, name: str, default_dir: Path) -> Path:
    return default_dir if name == "default" else out / name


def log_path(d: Path) -> Path:
    for n in ("run.blf", "big.blf"):
        if (d / n).exists():
            return d / n
    return d / "run.blf"


def sim_command(name: str, d: Path) -> list[str]:
    s = SCENARIOS[name]
    seed = ("--seed", "0") if s.external else ("--seed", str(SEED))
    return ["nice", "-n", "10", str(BIN / "sim-controller"), "record", *s.sim, *seed,
            "--out", str(d / "run.blf"), "--truth", str(d / "truth.jsonl")]


def replay_command(log: Path, d: Path, config: Path | None) -> list[str]:
    cmd = ["nice", "-n", "10", str(BIN / "edge-monitor"), "replay", str(log), "--json", "--jsonl", str(d / "sym.jsonl")]
    if config is not None:
        cmd += ["--config", str(config)]
    return cmd


def own_params_config(params_json: Path, dest: Path) -> Path:
    """Agent TOML whose ``[joint.N.friction]`` tables are the simulated joints' parameters."""
    params = json.loads(params_json.read_text())
    lines = ["# each joint's own friction parameters (from the simulator's truth sidecar)"]
    for joint in params["joints"]:
        lines.append(f"[joint.{joint['joint']}.friction]")
        lines += [f"{k} = {float(v)!r}" for k, v in joint["friction"].items()]
    dest.write_text("\n".join(lines) + "\n")
    return dest


def run_scenario(name: str, out: Path, default_dir: Path) -> None:
    s = SCENARIOS[name]
    d = scenario_dir(out, name, default_dir)
    if (d / "stats.json").exists() and (d / "sym.jsonl").exists():
        print(f"{name}: done already ({d})")
        return
    d.mkdir(parents=True, exist_ok=True)
    (d / "sym.jsonl").unlink(missing_ok=True)
    config = None
    if s.log_of is not None:
        src = scenario_dir(out, s.log_of, default_dir)
        log = log_path(src)
        config = own_params_config(src / "truth.params.json", d / "agent_own.toml")
        for f in ("truth.jsonl", "truth.params.json"):
            shutil.copy(src / f, d / f)
    else:
        cmd = sim_command(name, d)
        print("$", " ".join(cmd[3:]), flush=True)
        subprocess.run(cmd, check=True)
        log = d / "run.blf"
    cmd = replay_command(log, d, config)
    print("$", " ".join(cmd[3:]), flush=True)
    with open(d / "stats.json", "w") as fh:
        subprocess.run(cmd, check=True, stdout=fh, stderr=subprocess.DEVNULL)
    if s.log_of is None and not s.keep_log:
        log.unlink(missing_ok=True)


# ------------------------------------------------------------------------------------------------ loading

@dataclass
class JointSeries:
    """Per-cycle arrays of one joint of one run (NaN where the agent published no value)."""

    cycle: np.ndarray
    temperature: np.ndarray        # true lubricant temperature
    motor_temperature: np.ndarray  # truth: lubricant + 5 + N(0, 3²)
    load: np.ndarray               # true |τl|
    wear: np.ndarray               # ϖ̂
    wear_std: np.ndarray
    wear_temperature: np.ndarray   # ξ̂ (posterior mean)
    kl_raw: np.ndarray             # log KL
    kl_weighted: np.ndarray        # log KL
    statistic: dict[str, np.ndarray] = field(default_factory=dict)
    threshold: dict[str, float] = field(default_factory=dict)
    first_alarm: dict[str, int | None] = field(default_factory=dict)
    change_cycle: dict[str, np.ndarray] = field(default_factory=dict)

    def quantity(self, q: str) -> np.ndarray:
        return getattr(self, q)


def _num(x: Any) -> float:
    return float("nan") if x is None else float(x)


def load_run(d: Path) -> dict[int, JointSeries]:
    truth = {}
    for line in (d / "truth.jsonl").read_text().splitlines():
        r = json.loads(line)
        if "joint" in r:
            truth[(r["joint"], r["cycle"])] = r
    per_joint: dict[int, list[dict]] = {}
    for line in (d / "sym.jsonl").read_text().splitlines():
        r = json.loads(line)
        if "kind" not in r:                     # alarm events are marked "kind": "alarm"
            per_joint.setdefault(r["joint"], []).append(r)
    out = {}
    for j, recs in sorted(per_joint.items()):
        recs.sort(key=lambda r: r["cycle"])
        t = [truth[(j, r["cycle"])] for r in recs]
        kl = lambda key: np.log(np.array([_num(r["kl"][key]) for r in recs]))  # noqa: E731
        s = JointSeries(
            cycle=np.array([r["cycle"] for r in recs]),
            temperature=np.array([x["temperature"] for x in t]),
            motor_temperature=np.array([x["motor_temperature"] for x in t]),
            load=np.abs(np.array([x["load"] for x in t])),
            wear=np.array([_num(r["wear"]["estimate"]) for r in recs]),
            wear_std=np.array([_num(r["wear"]["std"]) for r in recs]),
            wear_temperature=np.array([_num(r["wear"]["temperature"]) for r in recs]),
            kl_raw=kl("raw"), kl_weighted=kl("weighted"))
        for q in (*QUANTITIES, "joint"):
            s.statistic[q] = np.array([_num(r["decisions"][q]["statistic"]) for r in recs])
            s.change_cycle[q] = np.array([_num(r["decisions"][q]["change_cycle"]) for r in recs])
            thr = [r["decisions"][q]["threshold"] for r in recs if r["decisions"][q]["threshold"] is not None]
            s.threshold[q] = float(thr[0]) if thr else float("nan")
            alarms = [r["cycle"] for r in recs if r["decisions"][q]["alarm"]]
            s.first_alarm[q] = alarms[0] if alarms else None
        out[j] = s
    return out


# ------------------------------------------------------------------------------------------------ statistics

def learning_slice(x: np.ndarray) -> np.ndarray:
    """Indices of the first ``N_NOMINAL`` finite values (what the detector learns from)."""
    return np.flatnonzero(np.isfinite(x))[:N_NOMINAL]


def learn_stats(x: np.ndarray) -> tuple[float, float]:
    idx = learning_slice(x)
    return float(np.mean(x[idx])), float(np.std(x[idx], ddof=1))


def window_mean(x: np.ndarray, cycle: np.ndarray, c: int) -> float:
    m = (cycle >= c - REPORT_WINDOW) & (cycle < c) & np.isfinite(x)
    return float(np.mean(x[m])) if m.any() else float("nan")


def joint_vector(s: JointSeries) -> np.ndarray:
    return np.column_stack([s.wear, s.kl_raw, s.kl_weighted])


def mahalanobis_shift(s: JointSeries, c: int) -> float:
    """Distance of the mean 3-vector of cycles [c−20, c) from the learning mean, in learning-covariance units."""
    x = joint_vector(s)
    ok = np.all(np.isfinite(x), axis=1)
    learn = x[np.flatnonzero(ok)[:N_NOMINAL]]
    m = ok & (s.cycle >= c - REPORT_WINDOW) & (s.cycle < c)
    if not m.any() or len(learn) < N_NOMINAL:
        return float("nan")
    diff = x[m].mean(axis=0) - learn.mean(axis=0)
    return float(math.sqrt(diff @ np.linalg.solve(np.cov(learn.T), diff)))


def ols_slope(x: np.ndarray, y: np.ndarray) -> tuple[float, float]:
    """Slope and its standard error of y on x (finite pairs)."""
    m = np.isfinite(x) & np.isfinite(y)
    x, y = x[m], y[m]
    if x.size < 3 or np.ptp(x) == 0:
        return float("nan"), float("nan")
    a = np.column_stack([x - x.mean(), np.ones_like(x)])
    coef, res, *_ = np.linalg.lstsq(a, y, rcond=None)
    resid = y - a @ coef
    se = math.sqrt(resid @ resid / (x.size - 2) / np.sum((x - x.mean()) ** 2))
    return float(coef[0]), se


def monitoring(s: JointSeries, q: str) -> np.ndarray:
    """Mask of the cycles after the learning phase of quantity ``q``."""
    x = s.quantity(q)
    idx = learning_slice(x)
    m = np.isfinite(x)
    if idx.size:
        m &= s.cycle > s.cycle[idx[-1]]
    return m


def fmt(x: float, nd: int = 2) -> str:
    return "–" if x is None or not np.isfinite(x) else f"{x:.{nd}f}"


def pooled(runs: dict[int, JointSeries], fn) -> float:
    vals = [fn(s) for s in runs.values()]
    vals = [v for v in vals if np.isfinite(v)]
    return float(np.mean(vals)) if vals else float("nan")


def spread_cell(runs: dict[int, JointSeries], fn) -> str:
    """'mean (min … max)' of a per-joint number."""
    vals = np.array([fn(s) for s in runs.values()], dtype=float)
    vals = vals[np.isfinite(vals)]
    if not vals.size:
        return "–"
    return f"{vals.mean():.2f}" if vals.size == 1 else f"{vals.mean():.2f} ({vals.min():.2f} … {vals.max():.2f})"


# ------------------------------------------------------------------------------------------------ analyse

LABEL = {"wear": "ϖ̂", "kl_raw": "log kl.raw", "kl_weighted": "log kl.weighted"}


def analyse(out: Path, default_dir: Path, table_out: Path | None, plot_dir: Path | None) -> None:
    runs = {}
    for name in SCENARIOS:
        d = scenario_dir(out, name, default_dir)
        if (d / "sym.jsonl").exists() and (d / "truth.jsonl").exists():
            runs[name] = load_run(d)
    lines: list[str] = []
    w = lines.append
    base = runs.get("base")
    sigma_noise = {q: pooled(base, lambda s, q=q: float(np.nanstd(s.quantity(q)[monitoring(s, q)], ddof=1)))
                   for q in QUANTITIES} if base else {q: float("nan") for q in QUANTITIES}

    w("### Per-quantity mean and spread per scenario (all joints pooled; after each quantity's learning phase)\n")
    w("σ_noise = std of the quantity in `base` (no disturbance). Columns: mean ± std (of the per-cycle values).\n")
    w("| scenario | joints × cycles | T range °C | " + " | ".join(LABEL[q] for q in QUANTITIES) + " | wear std (published) |")
    w("|---|---|---|" + "---|" * len(QUANTITIES) + "---|")
    for name, r in runs.items():
        temps = np.concatenate([s.temperature for s in r.values()])
        cells = []
        for q in QUANTITIES:
            vals = np.concatenate([s.quantity(q)[monitoring(s, q)] for s in r.values()])
            cells.append(f"{fmt(np.mean(vals))} ± {fmt(np.std(vals, ddof=1))}" if vals.size > 1 else "–")
        wstd = np.nanmedian(np.concatenate([s.wear_std for s in r.values()]))
        n_c = max(len(s.cycle) for s in r.values())
        w(f"| {name} | {len(r)} × {n_c} | {temps.min():.1f} … {temps.max():.1f} | " + " | ".join(cells)
          + f" | {fmt(wstd, 1)} |")
    w("")
    w("σ_noise: " + ", ".join(f"{LABEL[q]} {fmt(sigma_noise[q], 3)}" for q in QUANTITIES) + "\n")

    w("### Drift vs the GLR's nominal (learned over the first 60 finite values of each quantity)\n")
    w("z(c) = (mean of cycles [c−20, c) − learning mean) / learning std, mean (min … max) over joints "
      "(joint vector: Mahalanobis distance of the 20-cycle mean vector under the learning covariance; "
      "noise floor of a 20-cycle mean: 0.22 σ scalar, ≈ 0.39 Mahalanobis in 3-d). Alarm = first alarm cycle per "
      "joint (– none). A sustained shift of δ σ over n cycles gives a Gaussian GLR ≈ n·δ²/2: with the "
      "thresholds 23.2 (d = 1) / 29.5 (d = 3) an alarm needs δ ≥ 0.68 σ (0.77 Mahalanobis) held over the "
      "100-cycle window, δ ≥ 1.4 σ over 25 cycles.\n")
    w("| scenario | quantity | learning mean ± std | z(100) | z(150) | z(200) | first alarm per joint |")
    w("|---|---|---|---|---|---|---|")
    for name, r in runs.items():
        if max(len(s.cycle) for s in r.values()) < 100:
            continue
        for q in (*QUANTITIES, "joint"):
            zs = []
            for c in REPORT_AT:
                if q == "joint":
                    zs.append(spread_cell(r, lambda s, c=c: mahalanobis_shift(s, c)))
                else:
                    def z(s, c=c, q=q):
                        mu, sd = learn_stats(s.quantity(q))
                        return (window_mean(s.quantity(q), s.cycle, c) - mu) / sd
                    zs.append(spread_cell(r, z))
            if q == "joint":
                learn = "(3-vector)"
            else:
                ms = [learn_stats(s.quantity(q)) for s in r.values()]
                learn = f"{fmt(float(np.mean([m for m, _ in ms])))} ± {fmt(float(np.mean([sd for _, sd in ms])))}"
            alarms = ", ".join("–" if s.first_alarm[q] is None else str(s.first_alarm[q]) for s in r.values())
            w(f"| {name} | {q} | {learn} | " + " | ".join(zs) + f" | {alarms} |")
    w("")

    w("### Character of every alarm: jump (short segment, one extreme value) or drift (long segment)\n")
    w("segment = alarm cycle − change_cycle reported by the GLR; statistic the cycle before → at the alarm; "
      "z of the alarm cycle's value and mean z over the segment, vs the learning mean/std (scalar quantities).\n")
    w("| scenario | joint | quantity | alarm cycle | change cycle | segment | statistic before → at | z at alarm | mean z over segment |")
    w("|---|---|---|---|---|---|---|---|---|")
    for name, r in runs.items():
        for j, s in r.items():
            for q in (*QUANTITIES, "joint"):
                a = s.first_alarm[q]
                if a is None:
                    continue
                i = int(np.flatnonzero(s.cycle == a)[0])
                ch = s.change_cycle[q][i]
                before = s.statistic[q][i - 1] if i else float("nan")
                if q == "joint":
                    z_at = z_seg = "–"
                else:
                    mu, sd = learn_stats(s.quantity(q))
                    seg = (s.cycle >= ch) & (s.cycle <= a) if np.isfinite(ch) else s.cycle == a
                    z_at = fmt((s.quantity(q)[i] - mu) / sd)
                    z_seg = fmt((np.nanmean(s.quantity(q)[seg]) - mu) / sd)
                w(f"| {name} | {j} | {q} | {a} | {fmt(ch, 0)} | {fmt(a - ch, 0)} | {fmt(before, 1)} → "
                  f"{fmt(s.statistic[q][i], 1)} | {z_at} | {z_seg} |")
    w("")

    w("### Trend with the disturbance (OLS over the monitoring cycles, all joints pooled)\n")
    w("Slope per °C (temperature scenarios) or per 0.1 of |τl| (load), in the quantity's units and in "
      "units of σ_noise and of the learning std σ_learn of that run.\n")
    w("| scenario | regressor | quantity | slope ± se | slope / σ_noise | slope / σ_learn |")
    w("|---|---|---|---|---|---|")
    for name, reg in (("temp_drift", "temperature"), ("temp_wide", "temperature"), ("default", "temperature"),
                      ("default_own", "temperature"), ("load", "load")):
        if name not in runs:
            continue
        r = runs[name]
        scale = 0.1 if reg == "load" else 1.0
        for q in QUANTITIES:
            xs = np.concatenate([getattr(s, reg)[monitoring(s, q)] for s in r.values()]) / scale
            ys = np.concatenate([s.quantity(q)[monitoring(s, q)] for s in r.values()])
            b, se = ols_slope(xs, ys)
            sl = pooled(r, lambda s, q=q: learn_stats(s.quantity(q))[1])
            w(f"| {name} | {'°C' if reg == 'temperature' else '0.1 load'} | {q} | {fmt(b, 3)} ± {fmt(se, 3)} | "
              f"{fmt(b / sigma_noise[q], 3)} | {fmt(b / sl, 3)} |")
    w("")

    fixed = {t: runs[f"temp_fixed_{t}"] for t in TEMPS if f"temp_fixed_{t}" in runs}
    if fixed:
        w("### Quantity vs fixed temperature (vary 0, load 0.5; each run learns its own KL nominal)\n")
        w("| T °C | ϖ̂ mean ± std | ξ̂ mean ± std | log kl.raw mean ± std | log kl.weighted mean ± std |")
        w("|---|---|---|---|---|")
        for t, r in fixed.items():
            def mean_std(q: str) -> str:
                v = np.concatenate([s.quantity(q)[np.isfinite(s.quantity(q))] for s in r.values()])
                return f"{fmt(v.mean())} ± {fmt(v.std(ddof=1))}"
            w(f"| {t} | {mean_std('wear')} | {mean_std('wear_temperature')} | {mean_std('kl_raw')} | "
              f"{mean_std('kl_weighted')} |")
        w("")

    if "temp_wide" in runs:
        w("### Wide drift: mean per 5 °C temperature bin (temp_wide, both joints; KL nominal = cycles 0–9)\n")
        r = runs["temp_wide"]
        t0 = float(np.mean([s.temperature[:10].mean() for s in r.values()]))
        w(f"KL nominal learned at {t0:.1f} °C (mean of cycles 0–9). Δ in σ_noise from the first bin.\n")
        w("| T bin °C | cycles | ϖ̂ | Δϖ̂/σ_noise | log kl.raw | Δ/σ_noise | log kl.weighted | Δ/σ_noise |")
        w("|---|---|---|---|---|---|---|---|")
        edges = np.arange(30, 75, 5)
        first: dict[str, float] = {}
        for lo in edges:
            cells = []
            n = 0
            for q in QUANTITIES:
                v = np.concatenate([s.quantity(q)[(s.temperature >= lo) & (s.temperature < lo + 5)
                                                  & np.isfinite(s.quantity(q))] for s in r.values()])
                n = max(n, v.size)
                m = float(v.mean()) if v.size else float("nan")
                first.setdefault(q, m)
                cells += [fmt(m), fmt((m - first[q]) / sigma_noise[q])]
            if n:
                w(f"| {lo}–{lo + 5} | {n} | " + " | ".join(cells) + " |")
        w("")

    vary_fixed = {t: runs[f"vary_fixed_{t}"] for t in TEMPS if f"vary_fixed_{t}" in runs}
    if vary_fixed:
        w("### (1)/(3) Wear estimate of ±8 % joints at fixed temperatures (load 0.5; mean over 30 cycles ± SE)\n")
        w("Default parameters (the agent's default) vs each joint's own parameters (`_own`).\n")
        joints = sorted(next(iter(vary_fixed.values())).keys())
        w("| T °C | " + " | ".join(f"j{j} default" for j in joints) + " | " + " | ".join(f"j{j} own" for j in joints) + " |")
        w("|---|" + "---|" * (2 * len(joints)))
        for t, r in vary_fixed.items():
            own = runs.get(f"vary_fixed_{t}_own", {})
            def cell(rr, j):
                if j not in rr:
                    return "–"
                v = rr[j].wear[np.isfinite(rr[j].wear)]
                return f"{v.mean():.1f} ± {v.std(ddof=1) / math.sqrt(v.size):.1f}"
            w(f"| {t} | " + " | ".join(cell(r, j) for j in joints) + " | " + " | ".join(cell(own, j) for j in joints) + " |")
        w("")

    if "default" in runs:
        w("### (4) Motor temperature (JointStatus) vs lubricant temperature, and the estimator's ξ̂ (full default)\n")
        w("| joint | T range °C | corr(motor T, T) | std(motor T − T − 5) °C | corr(ξ̂, T) | std(ξ̂ − T) °C | mean(ξ̂ − T) °C | corr of 10-cycle means (motor T) |")
        w("|---|---|---|---|---|---|---|---|")
        for j, s in runs["default"].items():
            res = s.motor_temperature - s.temperature - 5.0
            ok = np.isfinite(s.wear_temperature)
            n10 = len(s.temperature) // 10
            mt10 = s.motor_temperature[: n10 * 10].reshape(n10, 10).mean(axis=1)
            t10 = s.temperature[: n10 * 10].reshape(n10, 10).mean(axis=1)
            w(f"| {j} | {s.temperature.min():.1f} … {s.temperature.max():.1f} | "
              f"{np.corrcoef(s.motor_temperature, s.temperature)[0, 1]:.3f} | {res.std(ddof=1):.2f} | "
              f"{np.corrcoef(s.wear_temperature[ok], s.temperature[ok])[0, 1]:.3f} | "
              f"{np.std(s.wear_temperature[ok] - s.temperature[ok], ddof=1):.2f} | "
              f"{np.mean(s.wear_temperature[ok] - s.temperature[ok]):.2f} | {np.corrcoef(mt10, t10)[0, 1]:.3f} |")
        w("")
        w("### (5) Temperature span of the learning phase vs the rest (full default, true lubricant T)\n")
        w("| joint | cycles 0–9 (KL nominal) | cycles 0–59 (wear GLR) | cycles 10–69 (KL/joint GLR) | cycles 60–199 | cycles 70–199 |")
        w("|---|---|---|---|---|---|")
        for j, s in runs["default"].items():
            def rng_(a, b):
                t = s.temperature[(s.cycle >= a) & (s.cycle <= b)]
                return f"{t.min():.1f} … {t.max():.1f}"
            w(f"| {j} | {rng_(0, 9)} | {rng_(0, 59)} | {rng_(10, 69)} | {rng_(60, 199)} | {rng_(70, 199)} |")
        w("")

    text = "\n".join(lines)
    print(text)
    if table_out is not None:
        table_out.write_text(text + "\n")
    if plot_dir is not None:
        plot(runs, sigma_noise, plot_dir)


def plot(runs: dict[str, dict[int, JointSeries]], sigma_noise: dict[str, float], plot_dir: Path) -> None:
    try:
        import matplotlib
        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
    except ImportError:
        print("matplotlib not installed: no plots", file=sys.stderr)
        return
    plot_dir.mkdir(parents=True, exist_ok=True)
    # 1. quantities vs cycle, per scenario (joint 0), with the learning mean ± 1σ band
    names = [n for n in ("base", "temp_drift", "temp_wide", "load", "vary", "default") if n in runs]
    fig, axes = plt.subplots(len(QUANTITIES) + 1, len(names), figsize=(3.3 * len(names), 9), sharex=True,
                             squeeze=False)
    for col, name in enumerate(names):
        r = runs[name]
        for row, q in enumerate(QUANTITIES):
            ax = axes[row, col]
            for _joint, s in r.items():
                x = s.quantity(q)
                ax.plot(s.cycle, x, lw=0.6, alpha=0.7)
                mu, sd = learn_stats(x)
                idx = learning_slice(x)
                ax.fill_between([s.cycle[idx[0]], s.cycle[-1]], mu - sd, mu + sd, alpha=0.06, color="k")
                first = s.first_alarm[q]
                if first is not None:
                    ax.axvline(first, color="r", lw=0.6, alpha=0.6)
            ax.axvline(N_NOMINAL, color="k", ls=":", lw=0.6)
            if col == 0:
                ax.set_ylabel(LABEL[q])
            if row == 0:
                ax.set_title(name, fontsize=9)
        ax = axes[-1, col]
        for s in r.values():
            ax.plot(s.cycle, s.temperature, lw=0.8)
        ax.set_xlabel("cycle")
        if col == 0:
            ax.set_ylabel("lubricant T °C")
    fig.suptitle("Per-cycle quantities on healthy joints (red: first alarm; dotted: end of 60 learning cycles; "
                 "grey: learning mean ± σ)", fontsize=9)
    fig.tight_layout()
    fig.savefig(plot_dir / "quantities_vs_cycle.png", dpi=72)
    plt.close(fig)
    # 2. quantities vs temperature (temp_wide + fixed temperatures), in σ_noise
    if "temp_wide" in runs:
        fig, axes = plt.subplots(1, 3, figsize=(12, 3.6))
        for ax, q in zip(axes, QUANTITIES):
            for name, mk in (("temp_wide", "."), ("temp_drift", "x"), ("default", "+")):
                if name not in runs:
                    continue
                for s in runs[name].values():
                    x = s.quantity(q)
                    ax.plot(s.temperature, x, mk, ms=3, alpha=0.5, label=name if s is next(iter(runs[name].values())) else None)
            ts = [t for t in TEMPS if f"temp_fixed_{t}" in runs and q == "wear"]
            if ts:
                means = [np.nanmean(np.concatenate([s.wear for s in runs[f"temp_fixed_{t}"].values()])) for t in ts]
                ax.plot(ts, means, "ks-", label="fixed T (mean)")
            ax.set_xlabel("lubricant temperature °C")
            ax.set_ylabel(LABEL[q])
            ax.set_title(f"{LABEL[q]} (σ_noise = {sigma_noise[q]:.2f})", fontsize=9)
            ax.legend(fontsize=7)
        fig.tight_layout()
        fig.savefig(plot_dir / "quantities_vs_temperature.png", dpi=90)
        plt.close(fig)
    # 3. wear estimate of varied joints vs temperature, default vs own parameters
    vf = [t for t in TEMPS if f"vary_fixed_{t}" in runs]
    if vf:
        fig, ax = plt.subplots(figsize=(6, 4))
        joints = sorted(runs[f"vary_fixed_{vf[0]}"].keys())
        for j in joints:
            m = [np.nanmean(runs[f"vary_fixed_{t}"][j].wear) for t in vf]
            line, = ax.plot(vf, m, "o-", label=f"j{j} default")
            own = [np.nanmean(runs[f"vary_fixed_{t}_own"][j].wear) if f"vary_fixed_{t}_own" in runs else np.nan
                   for t in vf]
            ax.plot(vf, own, "x--", color=line.get_color(), alpha=0.7)
        ax.set_xlabel("lubricant temperature °C (fixed)")
        ax.set_ylabel("mean ϖ̂ over 30 cycles (true wear 0)")
        ax.set_title("±8 % joints: default parameters (o) vs own parameters (x)", fontsize=9)
        ax.legend(fontsize=7, ncol=2)
        fig.tight_layout()
        fig.savefig(plot_dir / "wear_vs_temperature_varied.png", dpi=90)
        plt.close(fig)
    print(f"plots in {plot_dir}")


# ------------------------------------------------------------------------------------------------ biasmap

def biasmap(n_joints: int, n_noisy_joints: int, draws: int, seed: int, out_json: Path | None) -> None:
    from edge_monitor.features.wear_estimation import WearEstimator
    from joint_model import DEFAULT_PARAMS, FRICTION_NOISE_STD
    from joint_model.friction import friction_magnitude
    from sim_controller.config import DEFAULT_SPEEDS
    from sim_controller.controller import VARIED_PARAMS

    rng = np.random.default_rng(seed)
    v = np.asarray(DEFAULT_SPEEDS)
    temps = np.array([30.0, 31.0, 32.0, 33.0, 35.0, 37.5, 40.0, 42.5, 45.0, 47.5, 49.0, 50.0, 52.5, 55.0, 60.0, 65.0, 70.0])
    at = {float(t): k for k, t in enumerate(temps)}
    factors = rng.uniform(0.92, 1.08, size=(n_joints, len(VARIED_PARAMS)))
    joints = [replace(DEFAULT_PARAMS, **{n: getattr(DEFAULT_PARAMS, n) * f for n, f in zip(VARIED_PARAMS, fs)})
              for fs in factors]
    est_default = WearEstimator(method="marginal")
    results: dict[str, Any] = {"temperatures": temps.tolist(), "params": list(VARIED_PARAMS)}
    for true_wear in (0.0, 20.0):
        table = np.empty((2, n_joints, temps.size))
        for j, p in enumerate(joints):
            own = WearEstimator(params=p, method="marginal")
            for k, t in enumerate(temps):
                tau = friction_magnitude(v, 0.5, t, true_wear, p)
                table[0, j, k] = est_default.estimate(v, tau, 0.5, 0.1).estimate - true_wear
                table[1, j, k] = own.estimate(v, tau, 0.5, 0.1).estimate - true_wear
        results[f"noise_free_bias_w{true_wear:g}"] = {"default": table[0].tolist(), "own": table[1].tolist()}
        print(f"\n#### Noise-free bias ϖ̂ − ϖ at true wear {true_wear:g} ({n_joints} random ±8 % joints, load 0.5)\n")
        print("| T °C | default: mean | default: std over joints | default: 5 % … 95 % | own: mean | own: std |")
        print("|---|---|---|---|---|---|")
        for k, t in enumerate(temps):
            d, o = table[0, :, k], table[1, :, k]
            print(f"| {t} | {d.mean():.2f} | {d.std(ddof=1):.2f} | {np.percentile(d, 5):.1f} … {np.percentile(d, 95):.1f} "
                  f"| {o.mean():.2f} | {o.std(ddof=1):.2f} |")
        if true_wear == 20.0:
            # per-joint temperature dependence of the bias and which parameters drive it (unclipped case)
            for name, est in (("default params", 0), ("own params", 1)):
                for lo, hi in ((33.0, 47.5), (30.0, 50.0), (50.0, 70.0)):
                    sl = (table[est, :, at[hi]] - table[est, :, at[lo]]) / (hi - lo)
                    print(f"\nPer-joint change of the bias {lo:g} → {hi:g} °C ({name}, true wear 20): mean {sl.mean():+.3f}, "
                          f"std over joints {sl.std(ddof=1):.3f}, 95 % of |·| ≤ {np.percentile(np.abs(sl), 95):.3f} wear/°C")
            x = np.column_stack([(factors - 1.0) * 100.0, np.ones(n_joints)])
            for label, y in (("bias at 40 °C", table[0, :, at[40.0]]),
                             ("bias change 33→47.5 °C", table[0, :, at[47.5]] - table[0, :, at[33.0]])):
                coef, *_ = np.linalg.lstsq(x, y, rcond=None)
                r2 = 1 - np.sum((y - x @ coef) ** 2) / np.sum((y - y.mean()) ** 2)
                print(f"\nLinear sensitivity of the {label} to +1 % of each parameter (R² = {r2:.2f}):\n")
                print("| " + " | ".join(VARIED_PARAMS) + " |")
                print("|" + "---|" * len(VARIED_PARAMS))
                print("| " + " | ".join(f"{c:+.2f}" for c in coef[:-1]) + " |")
                results[f"sensitivity_{label}"] = dict(zip(VARIED_PARAMS, coef[:-1].tolist()))
    if n_noisy_joints and draws:
        print(f"\n#### Noisy data as the agent sees it: mean ϖ̂ (true 0), {n_noisy_joints} joints × {draws} cycles per T "
              f"(σm = {FRICTION_NOISE_STD}, load 0.5 known to σl = 0.1)\n")
        print("| T °C | vary 0: mean ± std | ±8 % default params: mean of joint means | std of joint means | own params: mean |")
        print("|---|---|---|---|---|")
        noisy = np.empty((3, n_noisy_joints, temps.size))
        spread = np.empty(temps.size)
        for k, t in enumerate(temps):
            per_draw = []
            for j in range(n_noisy_joints):
                p = joints[j]
                own = WearEstimator(params=p, method="marginal")
                load = 0.5 + rng.normal(0.0, 0.1, draws)    # μl = 0.5 reported, true load differs by σl
                noise = rng.normal(0.0, FRICTION_NOISE_STD, (draws, v.size))
                tau_nom = friction_magnitude(v[None, :], load[:, None], t, 0.0, DEFAULT_PARAMS) + noise
                tau_var = friction_magnitude(v[None, :], load[:, None], t, 0.0, p) + noise
                e0 = [est_default.estimate(v, x, 0.5, 0.1).estimate for x in tau_nom]
                e1 = [est_default.estimate(v, x, 0.5, 0.1).estimate for x in tau_var]
                e2 = [own.estimate(v, x, 0.5, 0.1).estimate for x in tau_var]
                noisy[:, j, k] = np.mean(e0), np.mean(e1), np.mean(e2)
                per_draw += e0
            spread[k] = np.std(per_draw, ddof=1)
            print(f"| {t} | {noisy[0, :, k].mean():.2f} ± {spread[k]:.2f} | {noisy[1, :, k].mean():.2f} | "
                  f"{noisy[1, :, k].std(ddof=1):.2f} | {noisy[2, :, k].mean():.2f} |")
        results["noisy_mean_estimate"] = {"vary0": noisy[0].tolist(), "default": noisy[1].tolist(), "own": noisy[2].tolist(),
                                          "vary0_std_per_cycle": spread.tolist()}
    if out_json is not None:
        out_json.write_text(json.dumps(results) + "\n")


def plot_biasmap(results_json: Path, plot_dir: Path) -> None:
    """Mean wear estimate of healthy joints vs temperature from the ``biasmap --json`` output."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    res = json.loads(results_json.read_text())
    temps = np.asarray(res["temperatures"])
    fig, ax = plt.subplots(figsize=(7, 4.2))
    nf = res["noise_free_bias_w0"]
    d = np.asarray(nf["default"])
    ax.fill_between(temps, np.percentile(d, 5, axis=0), np.percentile(d, 95, axis=0), alpha=0.2, color="C0",
                    label="noise-free, ±8 % joints, default params: 5 … 95 %")
    ax.plot(temps, d.mean(axis=0), "C0-", label="noise-free, ±8 % joints, default params: mean")
    ax.plot(temps, np.asarray(nf["own"]).mean(axis=0), "C2--", label="noise-free, own params")
    if "noisy_mean_estimate" in res:
        nz = res["noisy_mean_estimate"]
        v0, sd = np.asarray(nz["vary0"]).mean(axis=0), np.asarray(nz["vary0_std_per_cycle"])
        ax.errorbar(temps, v0, yerr=sd, fmt="k.-", capsize=2, lw=1, label="noisy cycles, vary 0 (= own params): mean ± per-cycle std")
        dm = np.asarray(nz["default"])
        ax.plot(temps, dm.mean(axis=0), "C3.-", label="noisy cycles, ±8 % joints, default params: mean of joint means")
    ax.axvspan(30, 50, color="0.9", zorder=-1)
    ax.text(31, 47, "estimator's ξ prior U(30, 50)", fontsize=7)
    ax.set_xlabel("lubricant temperature °C (constant)")
    ax.set_ylabel("ϖ̂ (true wear 0), load 0.5")
    ax.set_title("Wear estimate of healthy joints vs temperature (marginal ML, 12 levels)", fontsize=9)
    ax.legend(fontsize=6.5, loc="upper left", bbox_to_anchor=(0.0, 0.93))
    fig.tight_layout()
    plot_dir.mkdir(parents=True, exist_ok=True)
    fig.savefig(plot_dir / "wear_bias_vs_temperature.png", dpi=90)
    plt.close(fig)


# ------------------------------------------------------------------------------------------------ segments

def segments(name: str, out: Path, default_dir: Path, joints: Iterable[int] | None, cycles: int | None) -> dict:
    """KL distances of parts of the cycle, per cycle, from the decoded log of a finished run. Written (commit
    583d7d1) for the KL monitor and ingest of the layout before commit 410bf98 (``edge_monitor.kl_monitor``:
    a ``KLMonitor`` with keyword settings and ``add``; ``Ingest.process``); the agent's KL distances have
    changed since (``KLConfig``: load and temperature compensation, ``min_speed``), so it is not ported: the
    segment tables of docs/studies/DISTURBANCE_STUDY.md are that agent's."""
    raise SystemExit("disturbance_study segments: written for the agent before commit 410bf98 (its KL monitor is "
                     "gone); to rerun it, check out 9601fea and take this part from commit 583d7d1 "
                     "(segments-table still reads the segments.json files it wrote)")


def _load_segments(out: Path, default_dir: Path, name: str) -> dict[str, dict[int, dict[int, tuple[float, float]]]]:
    raw = json.loads((out / name / "segments.json").read_text())
    series: dict[str, dict[int, dict[int, tuple[float, float]]]] = {}
    for key, vals in raw.items():
        j, sub = key.split("|", 1)
        series.setdefault(sub, {})[int(j)] = {int(c): tuple(v) for c, v in vals.items()}
    return series


def _log_series(vals: dict[int, tuple[float, float]], ch: int) -> tuple[np.ndarray, np.ndarray]:
    cyc = np.array(sorted(vals))
    with np.errstate(divide="ignore", invalid="ignore"):
        return cyc, np.log(np.array([vals[c][ch] for c in cyc], dtype=float))

def segments_table(out: Path, default_dir: Path, pairs: list[str], plot_dir: Path | None) -> None:
    """Per part of the cycle: σ of log KL in the noise run, and for each drift run the shift of log KL
    from its first monitored cycles (10–19) to its last 10 cycles, in that σ. ``pairs``: DRIFT:NOISE."""
    runs = [p.split(":") for p in pairs]
    segs = {n: _load_segments(out, default_dir, n) for pair in runs for n in pair}
    truths = {d: load_run(scenario_dir(out, d, default_dir)) for d, _ in runs}
    header = " | ".join(f"{d}: Δ raw | {d}: Δ weighted" for d, _ in runs)
    print("σ = std of log KL of the part over cycles ≥ 10 of the noise run (after its own 10-cycle nominal); "
          "Δ = (mean of the last 10 cycles − mean of cycles 10–19) / σ, mean over joints.\n")
    print("| part | " + " | ".join(f"σ raw ({n}) | σ weighted ({n})" for n in dict.fromkeys(n for _, n in runs)) + f" | {header} |")
    print("|---|" + "---|---|" * len(dict.fromkeys(n for _, n in runs)) + "---|---|" * len(runs))
    sigma: dict[tuple[str, str, int], float] = {}
    for sub in segs[runs[0][0]]:
        cells = []
        for n in dict.fromkeys(n for _, n in runs):
            for ch in (0, 1):
                sds = []
                for vals in segs[n][sub].values():
                    cyc, x = _log_series(vals, ch)
                    x = x[(cyc >= 10) & np.isfinite(x)]
                    sds.append(np.std(x, ddof=1))
                sigma[(n, sub, ch)] = float(np.mean(sds))
                cells.append(f"{sigma[(n, sub, ch)]:.2f}")
        for d, n in runs:
            for ch in (0, 1):
                dz = []
                for vals in segs[d][sub].values():
                    cyc, x = _log_series(vals, ch)
                    last = cyc.max()
                    dz.append((np.nanmean(x[cyc > last - 10]) - np.nanmean(x[(cyc >= 10) & (cyc < 20)])) / sigma[(n, sub, ch)])
                cells.append(f"{np.mean(dz):+.1f}")
        print(f"| {sub} | " + " | ".join(cells) + " |")
    if plot_dir is None:
        return
    try:
        import matplotlib
        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
    except ImportError:
        return
    fig, axes = plt.subplots(len(runs), 2, figsize=(12, 3.8 * len(runs)), squeeze=False)
    parts = ["all", "production", "levels 0–6 (≤ 41.7)", "levels 7–11 (≥ 82.2)", "level1", "level5"]
    for row, (d, n) in enumerate(runs):
        temp, cycles = truths[d][0].temperature, truths[d][0].cycle
        for col, (ch, title) in enumerate(((0, "log kl.raw"), (1, "log kl.weighted"))):
            ax = axes[row, col]
            for sub in parts:
                cyc, x = _log_series(segs[d][sub][0], ch)
                ref = np.nanmean(x[(cyc >= 10) & (cyc < 20)])
                z = (x - ref) / sigma[(n, sub, ch)]
                smooth = np.convolve(np.nan_to_num(z), np.ones(9) / 9, mode="valid")   # 9-cycle running mean
                label = {"level1": "level 1 (8.7 rad/s)", "level5": "level 5 (35.1 rad/s)"}.get(sub, sub)
                ax.plot(np.interp(cyc[4:-4], cycles, temp), smooth, lw=1.2, label=label)
            ax.axhline(0.68, color="k", ls=":", lw=0.7)
            ax.set_xlabel("lubricant temperature °C")
            ax.set_ylabel("Δ log KL / σ_noise (9-cycle mean)")
            ax.set_title(f"{title} of parts of the cycle — {d}, joint 0 (σ from {n})", fontsize=9)
            ax.legend(fontsize=7)
    fig.tight_layout()
    plot_dir.mkdir(parents=True, exist_ok=True)
    fig.savefig(plot_dir / "kl_parts_vs_temperature.png", dpi=90)
    plt.close(fig)


# ------------------------------------------------------------------------------------------------ cli

def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", type=Path, default=Path("/tmp/dstudy"), help="run directory root")
    ap.add_argument("--default-dir", type=Path, default=Path("/tmp/i10"),
                    help="finished full-default run (big.blf, truth.jsonl, sym.jsonl, stats.json)")
    sub = ap.add_subparsers(dest="cmd", required=True)
    sub.add_parser("list", help="scenarios and their command lines")
    p = sub.add_parser("run", help="record + replay scenarios")
    p.add_argument("names", nargs="*", help="scenario names (default: all)")
    p = sub.add_parser("analyse", help="tables and plots from the finished runs")
    p.add_argument("--table-out", type=Path)
    p.add_argument("--plot-dir", type=Path)
    p = sub.add_parser("biasmap", help="offline wear-estimate bias of random ±8 %% joints vs temperature")
    p.add_argument("--joints", type=int, default=200)
    p.add_argument("--noisy-joints", type=int, default=12)
    p.add_argument("--draws", type=int, default=40)
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--json", type=Path)
    p = sub.add_parser("biasmap-plot", help="plot the biasmap --json output")
    p.add_argument("json", type=Path)
    p.add_argument("--plot-dir", type=Path, required=True)
    p = sub.add_parser("segments", help="KL of parts of the cycle for finished runs (needs their logs)")
    p.add_argument("names", nargs="+")
    p.add_argument("--joints", type=int, nargs="*")
    p.add_argument("--cycles", type=int)
    p = sub.add_parser("segments-table", help="table/plot from segments.json of drift and noise runs")
    p.add_argument("pairs", nargs="+", metavar="DRIFT:NOISE")
    p.add_argument("--plot-dir", type=Path)
    args = ap.parse_args(argv)
    os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
    if args.cmd == "list":
        for name, s in SCENARIOS.items():
            d = scenario_dir(args.out, name, args.default_dir)
            print(f"{name}: {s.what}")
            if s.log_of is None:
                print("   sim-controller record " + " ".join(sim_command(name, d)[5:]))
                print("   edge-monitor replay " + " ".join(replay_command(d / "run.blf", d, None)[5:]))
            else:
                print(f"   edge-monitor replay <log of {s.log_of}> --json --jsonl {d}/sym.jsonl --config {d}/agent_own.toml")
    elif args.cmd == "run":
        for name in args.names or list(SCENARIOS):
            if name not in SCENARIOS:
                raise SystemExit(f"unknown scenario {name!r}; see 'list'")
            run_scenario(name, args.out, args.default_dir)
    elif args.cmd == "analyse":
        analyse(args.out, args.default_dir, args.table_out, args.plot_dir)
    elif args.cmd == "biasmap":
        biasmap(args.joints, args.noisy_joints, args.draws, args.seed, args.json)
    elif args.cmd == "biasmap-plot":
        plot_biasmap(args.json, args.plot_dir)
    elif args.cmd == "segments":
        for name in args.names:
            segments(name, args.out, args.default_dir, args.joints, args.cycles)
    elif args.cmd == "segments-table":
        segments_table(args.out, args.default_dir, args.pairs, args.plot_dir)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
