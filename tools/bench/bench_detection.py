#!/usr/bin/env python3
"""Benchmark: detection speed of the agent's detectors against River's drift detectors, at the same
measured run length to false alarm (ARL0), on the agent's own per-cycle quantities.

Data: the simulator's cycle-level mode feeding the agent's real pipeline (edge_monitor.offline.fast_path):
healthy joints with the simulator defaults (individual variation, thermal drift, load spread), and
the same robots with linear wear ramps 0 → ``--wear-to`` over 50, 100, 200 cycles (``--slopes``)
starting at cycle ``--wear-start`` on every joint. Per joint and cycle: ``wear_score``, ``kl_raw``,
``kl_weighted`` (what the decision layer watches). Simulated sequences are cached in a .npz under
``--cache`` (default: a temp dir), never in the repository.

Procedure, per quantity:

1. ours: ``DetectorBank`` with ``decision.arl0_cycles = --target`` (the calibrated threshold of
   docs/DETECTION.md), run over every healthy sequence; after an alarm the detector is reset and
   relearns (as after a declared maintenance); measured ARL0 = monitored cycles / false alarms.
2. each River detector gets the same values in the units our detector watches (log for the KL
   distances), standardised by the mean and std of the first ``n_nominal`` cycles of the sequence (what
   our detector learns from), and is restarted (a new instance) after each alarm. Its main threshold
   parameter is set by bisection (on a log scale) so that its ARL0 on the same healthy sequences
   (cycles fed / alarms) matches our measured ARL0.
3. on the worn sequences: the first alarm at or after the wear start (alarms before it are false
   alarms: restart and go on), its delay in cycles after the start and the true wear at that cycle;
   the median over joints (a joint without an alarm by the end counts as "not detected", delay = ∞
   for the median).

    .venv/bin/python tools/bench/bench_detection.py                 # ≈ 10–20 min on 2 cores (simulation cached)
    .venv/bin/python tools/bench/bench_detection.py --quick         # 1 robot × 3 joints, fewer cycles (smoke)
"""

from __future__ import annotations

import argparse
import hashlib
import json
import logging
import math
import os
import platform
import sys
import tempfile
import time
from concurrent.futures import ProcessPoolExecutor
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable, Iterable

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))

from benchmark_report import write_report  # noqa: E402

from edge_monitor.features.registry import LOG_SCALE  # noqa: E402
from edge_monitor.features.registry import QUANTITIES as REGISTERED  # noqa: E402

log = logging.getLogger("bench_detection")

QUANTITIES = ("wear", "kl_raw", "kl_weighted")       # decision-layer quantities (each watches one input)
INPUT = {q: REGISTERED[q].inputs[0] for q in QUANTITIES}    # the value each watches
NOT_DETECTED = math.inf


# -- simulation (cached) ---------------------------------------------------------------------------------

def simulate(seed: int, cycles: int, joints: int, ramp: str | None) -> dict[str, np.ndarray]:
    """Per-cycle detector inputs of every joint (rows after model learning) with the true wear."""
    from edge_monitor.offline.fast_path import DETECTOR_INPUTS, detector_inputs
    from sim_controller.config import SimConfig, wear_profiles_from_ramps

    wear = wear_profiles_from_ramps([ramp], joints) if ramp else ()
    config = SimConfig(joints=joints, cycles=cycles, seed=seed, wear=wear)
    rows: dict[str, list[float]] = {k: [] for k in ("joint", "cycle", *DETECTOR_INPUTS)}
    for joint, cycle, values in detector_inputs(config):
        rows["joint"].append(joint)
        rows["cycle"].append(cycle)
        for k, v in values.items():
            rows[k].append(v)
    out = {k: np.asarray(v) for k, v in rows.items()}
    out["true_wear"] = np.array([config.wear_profile(int(j)).wear(int(c)) if config.wear else 0.0
                                 for j, c in zip(out["joint"], out["cycle"])])
    return out


@dataclass(frozen=True)
class Plan:
    seeds: tuple[int, ...]
    joints: int
    healthy_cycles: int
    slopes: tuple[int, ...]
    wear_start: int
    wear_to: float
    tail: int                  # cycles simulated after the ramp's end

    def jobs(self) -> list[tuple[str, int, int, int, str | None]]:
        out: list[tuple[str, int, int, int, str | None]] = [
            (f"healthy/{s}", s, self.healthy_cycles, self.joints, None) for s in self.seeds]
        for slope in self.slopes:
            end = self.wear_start + slope
            ramp = f"all:{self.wear_start}:{end}:0:{self.wear_to:g}"
            out += [(f"ramp{slope}/{s}", 100 + s, end + self.tail, self.joints, ramp) for s in self.seeds]
        return out

    def key(self) -> str:
        return hashlib.sha256(json.dumps(self.__dict__, sort_keys=True).encode()).hexdigest()[:12]


def _job(args: tuple[str, int, int, int, str | None]) -> tuple[str, dict[str, np.ndarray], float]:
    name, seed, cycles, joints, ramp = args
    logging.getLogger("edge_monitor").setLevel(logging.ERROR)
    started = time.monotonic()
    return name, simulate(seed, cycles, joints, ramp), time.monotonic() - started


def load_or_simulate(plan: Plan, cache: Path, workers: int) -> dict[str, dict[str, np.ndarray]]:
    path = cache / f"detection-{plan.key()}.npz"
    if path.exists():
        with np.load(path) as z:
            out: dict[str, dict[str, np.ndarray]] = {}
            for key in z.files:
                name, field = key.rsplit(":", 1)
                out.setdefault(name, {})[field] = z[key]
        log.info("simulated sequences from the cache %s", path)
        return out
    jobs = plan.jobs()
    log.info("simulating %d runs (%d robot-cycles) on %d processes; cached in %s", len(jobs),
             sum(j[2] for j in jobs), workers, path)
    out = {}
    with ProcessPoolExecutor(max_workers=workers) as pool:
        for name, data, wall in pool.map(_job, jobs):
            out[name] = data
            log.info("  %s: %d rows in %.0f s", name, len(data["cycle"]), wall)
    cache.mkdir(parents=True, exist_ok=True)
    arrays: dict[str, Any] = {f"{name}:{k}": v for name, data in out.items() for k, v in data.items()}
    np.savez_compressed(path, **arrays)
    return out


@dataclass
class Sequence:
    """One joint's run: watched values (log for the KL distances), cycles, true wear."""

    name: str
    joint: int
    cycle: np.ndarray
    values: dict[str, np.ndarray]         # quantity → raw values (as the agent reports them)
    true_wear: np.ndarray

    def watched(self, quantity: str) -> np.ndarray:
        x = self.values[quantity]
        return np.log(np.maximum(x, 1e-300)) if INPUT[quantity] in LOG_SCALE else x


def sequences(data: dict[str, dict[str, np.ndarray]], prefix: str) -> list[Sequence]:
    out = []
    for name in sorted(n for n in data if n.startswith(prefix + "/")):
        d = data[name]
        for j in np.unique(d["joint"]).tolist():
            rows = d["joint"] == j
            out.append(Sequence(name, int(j), d["cycle"][rows], {q: d[INPUT[q]][rows] for q in QUANTITIES},
                                d["true_wear"][rows]))
    return out


# -- our detectors ---------------------------------------------------------------------------------------

def ours_run(seq: Sequence, quantity: str, target: float, draws: int, start: int | None = None
             ) -> tuple[int, int, list[int]]:
    """Our detector over one sequence with renewal: (monitored cycles, alarms before ``start``,
    cycles of the alarms at or after ``start`` (all alarms if ``start`` is None))."""
    from edge_monitor.pipeline.detectors import DecisionConfig
    from studies.bank_replay import new_bank, replay_bank

    config = DecisionConfig(arl0_cycles=target, calibration_draws=draws, quantities=(quantity,))
    bank = new_bank(config)
    monitored = false_alarms = 0
    hits: list[int] = []
    rows = ({"cycle": int(cycle), **{INPUT[q]: float(seq.values[q][k]) for q in QUANTITIES}}
            for k, cycle in enumerate(seq.cycle.tolist()))          # no motor temperature: warm-up stage only
    for step in replay_bank(bank, rows, seq.joint, "r"):
        if start is not None and hits:
            break
        cycle, decision = step.cycle, step.decisions[quantity]
        if decision.state == "monitoring" and decision.threshold is not None:
            monitored += 1
        if decision.alarm:
            if start is None or cycle < start:
                false_alarms += 1
            else:
                hits.append(int(cycle))
            bank.detectors[quantity].reset()
    return monitored, false_alarms, hits


# -- River -----------------------------------------------------------------------------------------------

@dataclass(frozen=True)
class RiverSpec:
    """A River detector: ``make(param)`` builds one; ``param`` is bisected on a log scale in
    [``low``, ``high``]; ``larger_is_stricter``: a larger value gives fewer alarms."""

    name: str
    make: Callable[[float], Any]
    param: str
    low: float
    high: float
    larger_is_stricter: bool
    unit_interval: bool = False          # input mapped to [0, 1] (HDDM's Hoeffding bounds)


def river_specs() -> list[RiverSpec]:
    from river import drift
    from river.drift import binary

    return [
        RiverSpec("ADWIN (clock=1)", lambda p: drift.ADWIN(delta=p, clock=1), "delta", 1e-15, 0.5, False),
        RiverSpec("PageHinkley (up, δ=0.005 default)",
                  lambda p: drift.PageHinkley(threshold=p, delta=0.005, mode="up"), "threshold", 0.5, 5000.0, True),
        RiverSpec("PageHinkley (up, δ=0.75 = our allowance)",
                  lambda p: drift.PageHinkley(threshold=p, delta=0.75, mode="up"), "threshold", 0.05, 2000.0, True),
        RiverSpec("KSWIN (window 100, stat 30)", lambda p: drift.KSWIN(alpha=p, seed=1), "alpha", 1e-12, 0.5, False),
        RiverSpec("HDDM_A (one-sided)", lambda p: binary.HDDMA(drift_confidence=p, warning_confidence=min(0.5, 5 * p)),
                  "drift_confidence", 1e-15, 0.5, False, unit_interval=True),
        RiverSpec("HDDM_W (one-sided)", lambda p: binary.HDDMW(drift_confidence=p, warning_confidence=min(0.5, 5 * p)),
                  "drift_confidence", 1e-15, 0.5, False, unit_interval=True),
    ]


def standardised(seq: Sequence, quantity: str, n_nominal: int, unit_interval: bool) -> list[float]:
    """The watched values in units of the first ``n_nominal`` cycles' spread (HDDM: mapped to [0, 1]
    as 0.5 + z/8, clipped: ±4 σ of the learned spread fill the interval)."""
    x = seq.watched(quantity)
    head = x[:n_nominal]
    z = (x - head.mean()) / max(float(head.std(ddof=1)), 1e-12)
    if unit_interval:
        z = np.clip(0.5 + z / 8.0, 0.0, 1.0)
    return z.tolist()


def river_run(spec: RiverSpec, param: float, xs: list[float], cycles: list[int], start: int | None = None
              ) -> tuple[int, int, list[int]]:
    """As :func:`ours_run` for a River detector (restarted after each alarm; every cycle counts)."""
    det = spec.make(param)
    false_alarms = 0
    hits: list[int] = []
    for x, cycle in zip(xs, cycles):
        det.update(x)
        if det.drift_detected:
            if start is None or cycle < start:
                false_alarms += 1
            else:
                hits.append(cycle)
                break
            det = spec.make(param)
    return len(xs), false_alarms, hits


def river_arl0(spec: RiverSpec, param: float, streams: list[tuple[list[float], list[int]]]) -> float:
    cycles = alarms = 0
    for xs, cs in streams:
        n, a, _ = river_run(spec, param, xs, cs)
        cycles += n
        alarms += a
    return cycles / alarms if alarms else math.inf


def bisect_param(arl0: Callable[[float], float], target: float, low: float, high: float,
                 larger_is_stricter: bool, steps: int = 14) -> tuple[float, float]:
    """The parameter in [low, high] (log scale) whose ARL0 is closest to ``target``: bisection on
    log(param) assuming ARL0 monotone in it (increasing if ``larger_is_stricter``). ``target`` inf (no
    false alarm at all): the most lenient parameter found without an alarm. Returns (param, its ARL0)."""
    lo, hi = math.log(low), math.log(high)
    best_p, best_a, best_err = low, math.nan, math.inf
    for _ in range(steps):
        mid = 0.5 * (lo + hi)
        p = math.exp(mid)
        a = arl0(p)
        if math.isinf(target):       # ours never alarmed: the most lenient setting without an alarm
            err = 0.0 if math.isinf(a) else math.inf
        else:
            err = abs(math.log(a / target)) if math.isfinite(a) and a > 0 else math.inf
        if err <= best_err or math.isnan(best_a):
            best_p, best_a, best_err = p, a, err
        too_strict = math.isinf(a) if math.isinf(target) else a > target
        if too_strict == larger_is_stricter:       # too strict: move towards the lenient end
            hi = mid
        else:
            lo = mid
    return best_p, best_a


# -- the comparison --------------------------------------------------------------------------------------

def delays(hits: Iterable[list[int]], start: int) -> list[float]:
    return [h[0] - start if h else NOT_DETECTED for h in hits]


def summary(values: list[float]) -> str:
    finite = [v for v in values if math.isfinite(v)]
    med = float(np.median(values)) if values else math.nan
    text = "—" if not math.isfinite(med) else f"{med:.0f}"
    missed = len(values) - len(finite)
    return text + (f" ({missed}/{len(values)} missed)" if missed else "")


def wear_at(seqs: list[Sequence], hits: list[list[int]]) -> str:
    got = [float(s.true_wear[np.searchsorted(s.cycle, h[0])]) for s, h in zip(seqs, hits) if h]
    if not got:
        return "—"
    return f"{np.median(got):.1f}"


def run(args: argparse.Namespace) -> dict[str, Any]:
    from edge_monitor.pipeline.detectors import DecisionConfig

    plan = Plan(tuple(range(1, args.robots + 1)), args.joints, args.healthy_cycles, tuple(args.slopes),
                args.wear_start, args.wear_to, args.tail)
    started = time.monotonic()
    data = load_or_simulate(plan, Path(args.cache), args.workers)
    sim_s = time.monotonic() - started
    healthy = sequences(data, "healthy")
    worn = {slope: sequences(data, f"ramp{slope}") for slope in plan.slopes}
    n_nominal = DecisionConfig().n_nominal
    results: dict[str, Any] = {"plan": plan.__dict__, "n_nominal": n_nominal, "target": args.target,
                               "quantities": {}}
    for q in QUANTITIES:
        t0 = time.monotonic()
        monitored = alarms = 0
        for seq in healthy:
            m, a, _ = ours_run(seq, q, args.target, args.draws)
            monitored += m
            alarms += a
        ours_arl0 = monitored / alarms if alarms else math.inf
        log.info("%s: ours ARL0 %.0f (%d alarms in %d monitored cycles), %.0f s", q, ours_arl0, alarms, monitored,
                 time.monotonic() - t0)
        rows: list[dict[str, Any]] = []
        ours_hits = {slope: [ours_run(s, q, args.target, args.draws, start=plan.wear_start)[2] for s in seqs]
                     for slope, seqs in worn.items()}
        rows.append({"detector": f"ours (GLR, arl0_cycles={args.target:g})", "param": "arl0_cycles",
                     "value": args.target, "arl0": ours_arl0, "false_alarms": alarms,
                     **{f"delay_{sl}": delays(h, plan.wear_start) for sl, h in ours_hits.items()},
                     **{f"wear_{sl}": wear_at(worn[sl], h) for sl, h in ours_hits.items()}})
        match = ours_arl0          # inf: ours never alarmed; River gets its most lenient alarm-free setting
        for spec in river_specs():
            if args.only and not any(o.lower() in spec.name.lower() for o in args.only):
                continue
            t0 = time.monotonic()
            streams = [(standardised(s, q, n_nominal, spec.unit_interval), s.cycle.tolist()) for s in healthy]
            def arl0_of(p: float, sp: RiverSpec = spec, st: list[tuple[list[float], list[int]]] = streams) -> float:
                return river_arl0(sp, p, st)

            param, arl0 = bisect_param(arl0_of, match, spec.low, spec.high, spec.larger_is_stricter, args.bisect_steps)
            hits = {sl: [river_run(spec, param, standardised(s, q, n_nominal, spec.unit_interval), s.cycle.tolist(),
                                   start=plan.wear_start)[2] for s in seqs] for sl, seqs in worn.items()}
            rows.append({"detector": spec.name, "param": spec.param, "value": param, "arl0": arl0,
                         **{f"delay_{sl}": delays(h, plan.wear_start) for sl, h in hits.items()},
                         **{f"wear_{sl}": wear_at(worn[sl], h) for sl, h in hits.items()}})
            log.info("%s: %s %s=%.3g ARL0 %.0f (target %.0f), %.0f s", q, spec.name, spec.param, param, arl0, match,
                     time.monotonic() - t0)
        results["quantities"][q] = rows
        results.setdefault("healthy_cycles", {})[q] = {"ours": monitored, "river": sum(len(s.cycle) for s in healthy)}
    results["wall_s"] = time.monotonic() - started
    results["simulation_s"] = sim_s
    return results


def markdown(results: dict[str, Any], args: argparse.Namespace) -> str:
    plan = results["plan"]
    slopes = plan["slopes"]
    n_healthy = len(plan["seeds"]) * plan["joints"]
    lines = [
        "## Detection speed against River (`tools/bench/bench_detection.py`)",
        "",
        f"Per-cycle quantities of the agent (simulator cycle-level mode → the agent's pipeline, "
        f"`edge_monitor/offline/fast_path.py`): {n_healthy} healthy joints ({len(plan['seeds'])} robot(s) × "
        f"{plan['joints']} joints × {plan['healthy_cycles']} cycles, simulator defaults: individual variation, "
        f"thermal drift, load spread) and the same number of joints with a linear wear ramp 0 → "
        f"{plan['wear_to']:g} starting at cycle {plan['wear_start']} over {', '.join(map(str, slopes))} cycles "
        f"(other seeds), {plan['tail']} cycles after the ramp's end. Our detectors: `decision.arl0_cycles = "
        f"{results['target']:g}`, learning {results['n_nominal']} cycles, reset and relearn after each alarm. "
        "River detectors: the same values in the units ours watches (log for the KL distances), standardised "
        f"by the first {results['n_nominal']} cycles of each sequence, a new instance after each alarm; the main "
        "parameter bisected (log scale) until the ARL0 on the healthy sequences matches ours. Delay = first "
        "alarm at or after the wear start − start [cycles], median over joints (missed: no alarm by the end "
        "of the run, counted as ∞ in the median); wear at alarm = true wear (0 … 100, 35 = critical) at the "
        "alarm, median over the joints that alarmed.",
        "",
        f"Run: `{' '.join(['.venv/bin/python tools/bench/bench_detection.py', *_shown(args.argv)])}`" + f" on {platform.machine()} "
        f"Linux, {os.cpu_count()} cores, Python {platform.python_version()}, river {_river_version()}, "
        f"{time.strftime('%Y-%m-%d %H:%M UTC', time.gmtime())}; {results['wall_s'] / 60:.1f} min "
        f"({results['simulation_s'] / 60:.1f} min simulating or loading the cache).",
        "",
    ]
    for q, rows in results["quantities"].items():
        lines += [f"**{q}**", "",
                  "| detector | tuned parameter | ARL0 on healthy [cycles] | "
                  + " | ".join(f"median delay, ramp {s} [cycles]" for s in slopes) + " | "
                  + " | ".join(f"wear at alarm, ramp {s}" for s in slopes) + " |",
                  "|---|---|---:|" + "---:|" * (2 * len(slopes))]
        for k, r in enumerate(rows):
            cycles = results.get("healthy_cycles", {}).get(q, {}).get("river" if k else "ours")
            alarms = f" ({round(cycles / r['arl0'])} alarms)" if cycles and math.isfinite(r["arl0"]) else ""
            arl0 = (f"{r['arl0']:.0f}{alarms}" if math.isfinite(r["arl0"])
                    else f"no alarm in {cycles} cycles" if cycles else "no alarm")
            cells = [r["detector"], f"{r['param']} = {r['value']:.3g}", arl0]
            cells += [summary(r[f"delay_{s}"]) for s in slopes] + [r[f"wear_{s}"] for s in slopes]
            lines.append("| " + " | ".join(cells) + " |")
        lines.append("")
    lines += ["**Where ours is not the fastest** (median delay strictly shorter than ours; a shorter ARL0 "
              "means more false alarms than ours):", ""]
    beaten = []
    for q, rows in results["quantities"].items():
        ours = rows[0]
        for s in slopes:
            mine = float(np.median(ours[f"delay_{s}"]))
            faster = [f"{r['detector']} ({float(np.median(r[f'delay_{s}'])):.0f}, at ARL0 "
                      f"{r['arl0']:.0f} against our {ours['arl0']:.0f})" for r in rows[1:]
                      if float(np.median(r[f"delay_{s}"])) < mine]
            if faster:
                beaten.append(f"* {q}, ramp {s} (ours {mine:.0f}): " + ", ".join(faster))
    lines += beaten or ["* nowhere in this run."]
    lines += ["", DISCUSSION, ""]
    return "\n".join(lines) + "\n"


DISCUSSION = (
    "Reading the tables. (1) At equal measured ARL0 our GLR detects sooner than ADWIN, the default "
    "Page-Hinkley, KSWIN and both HDDM tests on the fast and middle ramps of every quantity, typically by "
    "5–40 cycles and 5–30 points of wear; on the KL distances ADWIN and the default Page-Hinkley need "
    "two to three times our delay. (2) A Page-Hinkley test given our allowance (δ = 0.75 σ of the learned "
    "values, one-sided) is as fast as ours or a few cycles faster, most on the slow ramp: it is then a "
    "one-sided CUSUM with the same allowance, which is the optimal detector for a sustained shift of about "
    "2δ, while our window-limited GLR pays for not knowing the size of the change (it maximises over it "
    "and over the change time within a 100-cycle window) and for a threshold calibrated for the least "
    "favourable healthy drift. What ours gives that it does not: a threshold derived from a stated false-"
    "alarm rate at the end of learning (River's thresholds had to be bisected here on healthy data that "
    "a user does not have), an estimate of the change time and size, and a miss probability. (3) On the "
    "slow ramp (0 → 60 over 200 cycles) of the wear score, ADWIN and KSWIN alarm earlier than ours: a slow "
    "drift looks like a change to detectors that compare two windows, while our statistic is capped by "
    "its allowance until the mean has moved 0.75 σ past the learned level; the wear at their alarm is "
    "lower too. (4) Caveats: the ARL0 figures rest on few false alarms (ours: see the log lines; healthy "
    "joints sit inside the allowance, so the measured ARL0 is several times the calibrated 200), so the "
    "matching is coarse; River gets the standardisation from the first 60 cycles that ours learns from, "
    "which is already more than its detectors assume; the HDDM tests need values in [0, 1] (here 0.5 + "
    "z/8) and do not reach our ARL0 even at their most lenient setting (“no alarm”: they are compared at "
    "a longer ARL0, which favours them and they are still slower). River's DDM, EDDM and FHDDM watch "
    "0/1 error streams and do not apply to real-valued quantities.")


def _shown(argv: list[str]) -> list[str]:
    """The command's arguments without output paths (--json/--out/--cache/--from-json and their values)."""
    out, skip = [], False
    for a in argv:
        if skip:
            skip = False
        elif a in ("--json", "--out", "--cache", "--from-json"):
            skip = True
        elif not a.startswith(("--json=", "--out=", "--cache=", "--from-json=")):
            out.append(a)
    return out


def _river_version() -> str:
    try:
        import river
        return str(river.__version__)
    except ImportError:
        return "not installed"


def parse_args(argv: list[str] | None = None) -> argparse.Namespace:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="1 robot × 3 joints, 300 healthy cycles (smoke test)")
    ap.add_argument("--robots", type=int, default=2)
    ap.add_argument("--joints", type=int, default=6)
    ap.add_argument("--healthy-cycles", type=int, default=500)
    ap.add_argument("--slopes", type=int, nargs="+", default=[50, 100, 200], help="ramp lengths [cycles]")
    ap.add_argument("--wear-start", type=int, default=100)
    ap.add_argument("--wear-to", type=float, default=60.0)
    ap.add_argument("--tail", type=int, default=100, help="cycles simulated after the ramp's end")
    ap.add_argument("--target", type=float, default=200.0, help="our decision.arl0_cycles")
    ap.add_argument("--draws", type=int, default=16, help="our calibration_draws (bootstrap detectors)")
    ap.add_argument("--bisect-steps", type=int, default=14)
    ap.add_argument("--only", nargs="*", help="River detectors whose name contains one of these")
    ap.add_argument("--workers", type=int, default=2, help="simulation processes")
    ap.add_argument("--cache", default=os.path.join(tempfile.gettempdir(), "edge-monitor-bench"),
                    help="directory of the cached simulated sequences (.npz)")
    ap.add_argument("--out", default="docs/benchmarks/detection.md")
    ap.add_argument("--json", help="also write the raw results here")
    ap.add_argument("--from-json", help="only write the doc from the raw results of an earlier run (--json)")
    args = ap.parse_args(argv)
    args.argv = list(sys.argv[1:] if argv is None else argv)
    if args.quick:
        args.robots, args.joints, args.healthy_cycles, args.tail = 1, 3, 300, 60
    return args


def main(argv: list[str] | None = None) -> int:
    args = parse_args(argv)
    logging.basicConfig(level=logging.INFO, format="%(asctime)s %(message)s", datefmt="%H:%M:%S", stream=sys.stderr)
    logging.getLogger("edge_monitor").setLevel(logging.ERROR)     # hundreds of expected healthy alarms
    if args.from_json:
        results = json.loads(Path(args.from_json).read_text())
        args.argv = [a for a in args.argv if not a.startswith("--from-json") and a != args.from_json]
    else:
        results = run(args)
    write_report(markdown(results, args), args.out, args.json, results, default=float)
    return 0


if __name__ == "__main__":
    sys.exit(main())
