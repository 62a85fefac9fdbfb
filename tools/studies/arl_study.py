"""Monte Carlo study of the decision layer (docs/ALGORITHMS.md §5–6), figures for docs/DETECTION.md.

Parts (all with fixed seeds; select with --part, default all):

* ``calibration`` — false-alarm rate of the known-change batch GLR under H0 for Gaussian, skewed
  (gamma, shape 2) and bimodal nominal data, N0 nominal points, N = 50 test points, Pf ∈ {0.05,
  0.01}, asymptotic χ² threshold and bootstrap threshold; every run refits the nominal model on a
  fresh nominal sample (S nominal sets × T test sets); the standard error accounts for the
  clustering by nominal set.
* ``power`` — detection rate of the Gaussian, KDE and GCE batch tests for shifts of 0.25 and 0.5
  nominal σ on skewed and bimodal nominal data, next to each test's measured false-alarm rate.
* ``gce`` — GCE sparsity and held-out log-likelihood against the KDE.
* ``sequential`` — run length to false alarm (ARL0) and detection delay of the agent's detector
  (learning 60 cycles, GCE density, window 100, recursive mode) for bias changes of 1, 2, 3 nominal σ.
  The windowed statistic does not depend on Pf, so one set of traces gives ARL0 and delay for every
  Pf: ARL0(h) = monitored steps / number of up-crossings of h (each up-crossing is one false alarm
  followed by a reset); delay = first step at or after the change where the statistic ≥ h.
* ``agent`` — the same ARL0/delay study for the quantities the agent actually watches, at its
  default settings (DecisionConfig: 60 learning cycles, window 100, recursive mode): the wear
  estimate and log ``kl.raw`` / log ``kl.weighted`` (GCE density, d = 1) and the joint 3-vector
  [wear, log kl.raw, log kl.weighted] (KDE density, d = 3). Nominal data are synthetic surrogates
  fitted to 95 healthy cycles of the demo (joint 0, see :data:`SURROGATE` and ``--fit-from``):
  wear = max(0, N(μ, σ²)), log KL ~ N(μ, σ²), tied by a Gaussian copula with the measured
  correlations. Shifts (k = 1, 2, 3 nominal σ) move the wear's latent normal (before the
  truncation at 0), for the vector along the wear axis only, and the log KL values additively.
  Besides the up-crossing ARL0, every row also gives the first-alarm ARL0 (each run's first crossing
  only; see ``_first_alarm_arl0``), which is not inflated by a badly learned nominal set that
  re-crosses h many times.

* ``allowance`` — the product's detector as configured (one-sided, drift allowance ``a`` σ, the
  threshold calibrated at the allowance boundary, winsorised at ±3 σ): for a = 0 and 0.75 (the
  shipped value; ``--allowances``), 32 learned
  Gaussian nominals (60 values each) with their own calibrated thresholds, the run length to false
  alarm at sustained shifts of 0, 0.25, 0.5, 0.75 σ (censored exponential estimate: cycles / alarms)
  and the median delay for shifts of 1, 2, 3 σ present from the first monitored cycle.

* ``learning`` — the steady stage's learning set and density: 16 nominals of N0 = 60 and of 240
  N(0, 1) values, fitted as a Gaussian and as a GCE, each calibrated for 10⁴ cycles at its learned
  nominal (the steady stage's calibration), run on N(0, 1) for 5 000 cycles: the first alarms, and the
  fraction within −ln 0.9 · 10⁴ ≈ 1 054 cycles (10 % for an exponential run length with mean 10⁴).

* ``--agent`` — the agent's own detectors (``DetectorBank`` at the shipped defaults) fed by the
  simulator's fast path: healthy joints with the default individual variation, thermal drift and
  load spread. The per-cycle quantities of each joint are computed once; then for each target ARL0
  (50 and 200; ``--targets``) the detectors run over them, with each cycle's motor temperature for
  their thermal settling test; a detector that alarms is acknowledged (its statistic restarts on the same
  nominal, as the agent handles an alarm judged false; ``--warm-up-alarm reset``: a warm-up one relearns
  instead, as after a declared maintenance, a renewal whose nominals, learned later in the warming, have absorbed
  the drift the warm-up calibration is for), and measured ARL0 = monitored cycles / false alarms. Prints ``{"rows": [{"quantity",
  "stage", "target_arl0", "measured_arl0", "runs", "false_alarms", ...}, ...], "other_rows": [...]}``:
  ``rows`` are the steady stage (the nominal learned again once the joint's temperature settled, the
  stage ``arl0_cycles`` is stated for), ``other_rows`` the warm-up stage (threshold at the drift
  allowance: healthy joints run longer there) and any ``--at-boundary`` rows (``runs``: detector
  runs over all joints, each started by a learning phase or, in the steady stage, an acknowledged
  false alarm; monitored cycles are those whose value the statistic tested). ``--quick``: 2 robots
  (seeds 1, 2) of 2 joints × 1 600 cycles (≈ 750 steady cycles per joint: the joints settle at
  ≈ 500–700 and learn for 240), the agent's 48 bootstrap detectors per calibration, in parallel
  processes (≈ 10 min on 2 cores, the fast path most of it); default 4 robots of 6 joints × 2000 cycles. ``--scenario FILE|NAME``
  runs every robot in a simulator scenario (its plant timeline: load steps, stops, ``plant_week``;
  seeds, joints and cycles as given here). ``--at-boundary`` adds warm-up rows
  (``"at_boundary": true``) where each detector's
  monitored values are moved up by ``allowance`` × the std of the values it learned (in the units it
  watches): the least favourable healthy drift, the one its threshold is calibrated for, so there the
  measured ARL0 should match the target; without the shift, healthy joints sit inside the allowance and
  run longer. ``--calibrate-at healthy_drift|boundary|nominal`` measures with that calibration instead
  of the shipped ``decision.calibrate_at`` (docs/DETECTION.md); ``--steady-at`` and
  ``--steady-density``, ``--steady-transform`` do the same for the steady nominal
  (``decision.steady_calibrate_at``, ``decision.steady_density``, ``decision.steady_transform``).

* ``--agent --curves`` — why a calibration alone cannot match healthy drifting data: for each
  quantity, the threshold h that gives each target (``--targets``) on the simulated healthy joints
  themselves (every joint's detector run with h as a free parameter: renewal after a crossing, as
  above), next to the median over joints of the thresholds the calibration finds for the same learned
  nominals, simulated on the learned nominal and at the allowance boundary (``threshold_curves``).

Usage: ``python tools/studies/arl_study.py [--part NAME ...] [--agent] [--quick] [--json OUT.json]``;
``--part agent`` alone takes about 5 minutes on this machine.
"""

from __future__ import annotations

import argparse
import json
import logging
import math
import os
import sys
import time
from pathlib import Path
from typing import TYPE_CHECKING, Any, Callable

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")     # tiny matrices: a threaded BLAS only spins

import numpy as np  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))

from scipy import stats  # noqa: E402

from edge_monitor.stats.densities import fit_density  # noqa: E402
from edge_monitor.stats.glr import bootstrap_statistics, glr_known_change, threshold_from_pf  # noqa: E402
from edge_monitor.stats.sequential_detector import DetectorConfig, SequentialDetector  # noqa: E402

if TYPE_CHECKING:
    from edge_monitor.pipeline.detectors import DetectorBank
    from edge_monitor.stats.sequential_detector import DetectorConfig

log = logging.getLogger("arl_study")


def _bimodal(rng: np.random.Generator, n: int) -> np.ndarray:
    pick = rng.random(n) < 0.5
    return np.where(pick, rng.normal(-2.0, 0.5, n), rng.normal(2.0, 0.5, n))


SHAPES: dict[str, Callable[[np.random.Generator, int], np.ndarray]] = {
    "gaussian": lambda rng, n: rng.normal(size=n),
    "skewed": lambda rng, n: rng.gamma(2.0, size=n),
    "bimodal": _bimodal,
}
#: standard deviation of each nominal shape (to express shifts in nominal σ)
SHAPE_SD = {"gaussian": 1.0, "skewed": math.sqrt(2.0), "bimodal": math.sqrt(4.25)}
PFS = (0.05, 0.01)


def calibration(n0: int, sets: int, tests: int, n_boot: int, seed: int,
                kinds: tuple[str, ...] = ("gauss", "kde", "gce"),
                bootstrap_kinds: tuple[str, ...] = ("gauss", "gce"),
                shapes: tuple[str, ...] = tuple(SHAPES)) -> list[dict]:
    """The KDE bootstrap (EM over N0 components per draw) is too slow for this machine: skipped
    unless "kde" is in ``bootstrap_kinds``."""
    rows = []
    all_boot = n_boot
    for shape, draw in SHAPES.items():
        if shape not in shapes:
            continue
        for kind in kinds:
            n_boot = all_boot if kind in bootstrap_kinds else 0
            rng = np.random.default_rng(seed)
            t0 = time.perf_counter()
            asym = np.zeros((sets, len(PFS)))
            boot = np.zeros((sets, len(PFS)))
            for s in range(sets):
                nominal = draw(rng, n0)[:, None]
                density = fit_density(nominal, kind)
                boot_h = np.quantile(bootstrap_statistics(nominal, density, 50, n_boot, seed + s),
                                     [1 - pf for pf in PFS]) if n_boot else None
                stats = np.array([glr_known_change(draw(rng, 50)[:, None], density).statistic
                                  for _ in range(tests)])
                for i, pf in enumerate(PFS):
                    asym[s, i] = np.mean(stats >= threshold_from_pf(pf, 1))
                    if boot_h is not None:
                        boot[s, i] = np.mean(stats >= boot_h[i])
            for i, pf in enumerate(PFS):
                for method, rates in (("asymptotic", asym), ("bootstrap", boot)):
                    if method == "bootstrap" and not n_boot:
                        continue
                    rate = float(rates[:, i].mean())
                    se = float(rates[:, i].std(ddof=1) / math.sqrt(sets))
                    rows.append({"shape": shape, "density": kind, "pf": pf, "threshold": method,
                                 "rate": rate, "se": se, "runs": sets * tests,
                                 "within_factor_2": bool(pf / 2 <= rate <= 2 * pf)})
                    print(json.dumps(rows[-1]), file=sys.stderr, flush=True)
            print(f"calibration {shape}/{kind}: {time.perf_counter() - t0:.0f} s", file=sys.stderr, flush=True)
    return rows


def power(n0: int, sets: int, tests: int, seed: int, shifts: tuple[float, ...] = (0.25, 0.5)) -> list[dict]:
    rows = []
    pf = 0.01
    for shape in ("skewed", "bimodal"):
        draw = SHAPES[shape]
        for kind in ("gauss", "kde", "gce"):
            rng = np.random.default_rng(seed)
            h0_hits: list[bool] = []
            hits: dict[float, list[bool]] = {k: [] for k in shifts}
            for _ in range(sets):
                density = fit_density(draw(rng, n0)[:, None], kind)
                h = threshold_from_pf(pf, 1)
                h0_hits += [glr_known_change(draw(rng, 50)[:, None], density).statistic >= h for _ in range(tests)]
                for k in shifts:
                    shift = k * SHAPE_SD[shape]
                    hits[k] += [glr_known_change(draw(rng, 50)[:, None] + shift, density).statistic >= h
                                for _ in range(tests)]
            row = {"shape": shape, "density": kind, "pf": pf, "false_alarm_rate": float(np.mean(h0_hits)),
                   "runs": sets * tests}
            row.update({f"detection_{k}sd": float(np.mean(hits[k])) for k in shifts})
            rows.append(row)
            print(f"power {shape}/{kind} done", file=sys.stderr, flush=True)
    return rows


def gce_quality(seed: int) -> list[dict]:
    rows = []
    for shape, draw in SHAPES.items():
        for n0 in (60, 200, 500):
            rng = np.random.default_rng(seed)
            nominal, held = draw(rng, n0)[:, None], draw(rng, 20_000)[:, None]
            t0 = time.perf_counter()
            gce = fit_density(nominal, "gce")
            fit_s = time.perf_counter() - t0
            kde = fit_density(nominal, "kde")
            rows.append({"shape": shape, "n0": n0, "components": gce.n_components,
                         "kept_percent": 100.0 * gce.n_components / n0, "fit_s": fit_s,
                         "heldout_ll_gce": float(gce.logpdf(held).mean()),
                         "heldout_ll_kde": float(kde.logpdf(held).mean())})
    return rows


def tracing_detector(dim: int = 1, **settings: Any) -> SequentialDetector:
    """A detector whose statistic the studies trace and threshold themselves: the asymptotic threshold
    of Pf = 1e-9 (no calibration run), two-sided, no allowance (the detector these studies measured)."""
    return SequentialDetector(DetectorConfig(dim=dim, pf=1e-9, **settings))


def _trace(detector: SequentialDetector, values: np.ndarray) -> np.ndarray:
    out = []
    for cycle, v in enumerate(values):
        d = detector.update(float(v), cycle)
        if d.state == "monitoring" and d.statistic is not None:
            out.append(d.statistic)
    return np.asarray(out)


def _upcrossings(trace: np.ndarray, h: float) -> int:
    above = trace >= h
    return int(above[0]) + int(np.sum(above[1:] & ~above[:-1]))


def h0_trace(shape: str, steps: int, rng: np.random.Generator, density: str = "gce", window: int = 100,
             n_nominal: int = 60, mode: str = "recursive") -> np.ndarray:
    """Statistic of one detector over ``steps`` monitored cycles of nominal data (fresh nominal set)."""
    return _trace(tracing_detector(n_nominal=n_nominal, density=density, window=window, mode=mode),
                  SHAPES[shape](rng, n_nominal + steps))


def h1_trace(shape: str, shift_sd: float, pre: int, post: int, rng: np.random.Generator, density: str = "gce",
             window: int = 100, n_nominal: int = 60, mode: str = "recursive") -> np.ndarray:
    """Statistic over ``pre`` nominal then ``post`` shifted monitored cycles (shift in nominal σ)."""
    values = SHAPES[shape](rng, n_nominal + pre + post)
    values[n_nominal + pre:] += shift_sd * SHAPE_SD[shape]
    return _trace(tracing_detector(n_nominal=n_nominal, density=density, window=window, mode=mode), values)


def _first_alarm_arl0(h0_traces: list[np.ndarray], h: float) -> dict:
    """ARL0 from the first crossing of each run only (the alarm is latched; a reset relearns a fresh
    density, i.e. starts a new run): exposure = Σ cycles to the first crossing (or the whole run if
    none), ARL0 = exposure / runs that crossed — the censored exponential estimate. Unlike the
    up-crossing count it is not inflated by one bad nominal set that crosses again and again."""
    exposure, alarmed = 0, 0
    for t in h0_traces:
        hit = np.flatnonzero(t >= h)
        exposure += int(hit[0]) + 1 if hit.size else len(t)
        alarmed += int(hit.size > 0)
    return {"runs_with_alarm": alarmed, "first_alarm_exposure": exposure,
            "arl0_first_alarm": exposure / alarmed if alarmed else None,
            "arl0_first_alarm_lower_bound_95": exposure / 3.0 if not alarmed else None}


def summarize(h0_traces: list[np.ndarray], h1_traces: dict[float, list[np.ndarray]], pre: int,
              pfs: tuple[float, ...], dim: int = 1) -> dict:
    """ARL0 and delay for every Pf from the same traces (the statistic does not depend on Pf);
    ``dim`` is the detector's dimension (h = ½·χ²_dim quantile)."""
    total = sum(len(t) for t in h0_traces)
    table = []
    for pf in pfs:
        h = threshold_from_pf(pf, dim)
        crossings = sum(_upcrossings(t, h) for t in h0_traces)
        row = {"pf": pf, "threshold": h, "h0_steps": total, "false_alarms": crossings,
               "arl0": (total / crossings) if crossings else None,
               "arl0_lower_bound_95": (total / 3.0) if not crossings else None}  # Poisson, zero events
        row.update(_first_alarm_arl0(h0_traces, h))
        for k, traces in h1_traces.items():
            delays, early = [], 0
            for t in traces:
                if np.any(t[:pre] >= h):
                    early += 1
                    continue
                hit = np.flatnonzero(t[pre:] >= h)
                delays.append(int(hit[0]) + 1 if hit.size else math.inf)
            finite = [d for d in delays if math.isfinite(d)]
            row[f"delay_{k:g}sd_median"] = float(np.median(delays)) if delays else None
            row[f"delay_{k:g}sd_mean_detected"] = float(np.mean(finite)) if finite else None
            row[f"missed_{k:g}sd"] = len(delays) - len(finite)
            row[f"early_alarms_{k:g}sd"] = early
        table.append(row)
    levels = np.arange(2.0, 40.5, 1.0)
    tail = [{"h": float(h), "upcrossings": sum(_upcrossings(t, h) for t in h0_traces)} for h in levels]
    return {"h0_steps": total, "table": table, "tail": tail}


def arl0_extrapolated(tail: list[dict], total_steps: int, target: float = 1e4, min_events: int = 5) -> float | None:
    """Threshold h with estimated ARL0 = ``target``: least-squares line through log(up-crossing rate)
    against h over the levels with at least ``min_events`` up-crossings, solved for rate = 1/target."""
    pts = [(t["h"], math.log(t["upcrossings"] / total_steps)) for t in tail if t["upcrossings"] >= min_events]
    if len(pts) < 3:
        return None
    h, y = np.array(pts).T
    slope, intercept = np.polyfit(h, y, 1)
    return float((math.log(1.0 / target) - intercept) / slope) if slope < 0 else None


def sequential(shape: str = "gaussian", runs_h0: int = 25, steps_h0: int = 2500, runs_h1: int = 60,
               pre: int = 100, post: int = 120, pfs: tuple[float, ...] = (1e-2, 1e-3, 1e-4, 1e-5, 1e-6, 1e-7,
                                                                        1e-8, 1e-9, 1e-10),
               density: str = "gce", window: int = 100, mode: str = "recursive",
               h0_seeds: tuple[int, ...] = (11, 13), h1_seed: int = 12) -> dict:
    """ARL0/delay study of docs/DETECTION.md: ``runs_h0`` H0 runs per seed in ``h0_seeds``; H1 runs
    interleave the shifts 1, 2, 3 σ per run from one generator (seed ``h1_seed``)."""
    t0 = time.perf_counter()
    h0 = []
    for seed in h0_seeds:
        rng = np.random.default_rng(seed)
        h0 += [h0_trace(shape, steps_h0, rng, density, window, mode=mode) for _ in range(runs_h0)]
    per_step = (time.perf_counter() - t0) / max(sum(len(t) for t in h0), 1)
    rng = np.random.default_rng(h1_seed)
    h1: dict[float, list[np.ndarray]] = {1.0: [], 2.0: [], 3.0: []}
    for _ in range(runs_h1):
        for k in h1:
            h1[k].append(h1_trace(shape, k, pre, post, rng, density, window, mode=mode))
    out = summarize(h0, h1, pre, pfs)
    out.update({"shape": shape, "density": density, "window": window, "mode": mode,
                "runs_h0": runs_h0 * len(h0_seeds), "steps_per_run": steps_h0, "runs_h1": runs_h1,
                "pre_change": pre, "post_change": post, "seconds_per_step": per_step,
                "h_for_arl0_1e4": arl0_extrapolated(out["tail"], out["h0_steps"])})
    return out


#: Surrogate of the agent's per-cycle nominal values, fitted to /tmp/demo9/symptoms.jsonl (joint 0,
#: 100 healthy cycles; the KL distances exist from cycle 5 on, so 95 complete vectors; reproduce
#: with ``--fit-from``): wear estimate [%] sample mean 9.18 and sd 5.01 (3 exact zeros in 100 cycles;
#: max(0, N(9.18, 5.01²)) puts 3.4 % at 0);
#: log kl.raw mean −3.08, sd 1.09; log kl.weighted mean −3.24, sd 0.96 (Shapiro p 0.05 / 0.03: close
#: to log-normal KL); Pearson correlations of [wear, log kl.raw, log kl.weighted] below; lag-1
#: autocorrelations 0.03 … 0.07 (< 2/√100), so cycles are drawn independently.
SURROGATE: dict[str, list] = {
    "mean": [9.18, -3.08, -3.24],
    "sd": [5.01, 1.09, 0.96],
    "corr": [[1.0, 0.03, 0.19], [0.03, 1.0, 0.67], [0.19, 0.67, 1.0]],
}
#: The agent's detectors: name → (columns of the surrogate vector, density, dimension).
AGENT_QUANTITIES: dict[str, tuple[list[int], str]] = {
    "wear": ([0], "gce"),
    "log_kl_raw": ([1], "gce"),
    "log_kl_weighted": ([2], "gce"),
    "joint": ([0, 1, 2], "kde"),
}
AGENT_PFS = (1e-4, 1e-6, 1e-8, 1e-9, 1e-10, 1e-11, 1e-12, 1e-14)


def fit_surrogate(path: Path, joint: int = 0) -> dict[str, list]:
    """Fit :data:`SURROGATE` to a symptoms JSONL log: cycles of ``joint`` with a finite wear
    estimate and positive KL distances; moments of [wear, log kl.raw, log kl.weighted]."""
    rows = []
    for line in path.read_text().splitlines():
        rec = json.loads(line)
        if rec.get("joint") != joint or "kind" in rec:      # alarm events are marked "kind": "alarm"
            continue
        w, kr, kw = rec["wear"]["estimate"], rec["kl"]["raw"], rec["kl"]["weighted"]
        if None not in (w, kr, kw) and kr > 0 and kw > 0:
            rows.append([w, math.log(kr), math.log(kw)])
    x = np.asarray(rows)
    if len(x) < 10:
        raise ValueError(f"{path}: only {len(x)} complete cycles for joint {joint}; need ≥ 10")
    return {"mean": x.mean(axis=0).round(2).tolist(), "sd": x.std(axis=0, ddof=1).round(2).tolist(),
            "corr": np.corrcoef(x.T).round(2).tolist(), "cycles": len(x)}


def surrogate_draw(rng: np.random.Generator, n: int, surrogate: dict[str, list],
                   wear_shift_sd: float = 0.0, column_shift_sd: tuple[int, float] | None = None) -> np.ndarray:
    """(n, 3) nominal vectors [wear, log kl.raw, log kl.weighted]: Gaussian copula with the
    surrogate's correlations; wear = max(0, latent). ``column_shift_sd`` = (column, k) adds k
    nominal sd to that column's latent value (before the wear truncation)."""
    z = rng.multivariate_normal(np.zeros(3), np.asarray(surrogate["corr"]), size=n)
    x = np.asarray(surrogate["mean"]) + z * np.asarray(surrogate["sd"])
    if column_shift_sd is not None:
        col, k = column_shift_sd
        x[:, col] += k * surrogate["sd"][col]
    x[:, 0] = np.maximum(x[:, 0], 0.0)
    return x


def _agent_trace(columns: list[int], density: str, values: np.ndarray, window: int, n_nominal: int) -> np.ndarray:
    dim = len(columns)
    detector = tracing_detector(dim, n_nominal=n_nominal, density=density, window=window, mode="recursive")
    out = []
    for cycle, v in enumerate(values[:, columns]):
        d = detector.update(v if dim > 1 else float(v[0]), cycle)
        if d.state == "monitoring" and d.statistic is not None:
            out.append(d.statistic)
    return np.asarray(out)


def agent_quantity(name: str, surrogate: dict[str, list], runs_h0: int = 40, steps_h0: int = 2500,
                   runs_h1: int = 40, pre: int = 100, post: int = 120, pfs: tuple[float, ...] = AGENT_PFS,
                   window: int = 100, n_nominal: int = 60, seed: int = 31) -> dict:
    """ARL0/delay of the agent's detector for ``name`` (a key of :data:`AGENT_QUANTITIES`) on
    surrogate nominal data; the H1 shift is applied to the quantity's own column (wear for the
    joint vector). Each run learns a fresh nominal density."""
    columns, density = AGENT_QUANTITIES[name]
    shift_column = columns[0]
    t0 = time.perf_counter()
    rng = np.random.default_rng(seed)
    h0 = [_agent_trace(columns, density, surrogate_draw(rng, n_nominal + steps_h0, surrogate), window, n_nominal)
          for _ in range(runs_h0)]
    rng = np.random.default_rng(seed + 1)
    h1: dict[float, list[np.ndarray]] = {1.0: [], 2.0: [], 3.0: []}
    for _ in range(runs_h1):
        for k in h1:
            values = surrogate_draw(rng, n_nominal + pre + post, surrogate)
            values[n_nominal + pre:] = surrogate_draw(rng, post, surrogate, column_shift_sd=(shift_column, k))
            h1[k].append(_agent_trace(columns, density, values, window, n_nominal))
    out = summarize(h0, h1, pre, pfs, dim=len(columns))
    out.update({"quantity": name, "density": density, "dim": len(columns), "window": window,
                "n_nominal": n_nominal, "mode": "recursive", "runs_h0": runs_h0, "steps_per_run": steps_h0,
                "runs_h1": runs_h1, "pre_change": pre, "post_change": post, "seed": seed,
                "seconds": time.perf_counter() - t0,
                "h_for_arl0_1e4": arl0_extrapolated(out["tail"], out["h0_steps"])})
    h = out["h_for_arl0_1e4"]
    out["pf_for_arl0_1e4"] = float(stats.chi2.sf(2.0 * h, len(columns))) if h is not None else None
    print(f"agent {name}: {out['seconds']:.0f} s", file=sys.stderr, flush=True)
    return out


def agent(surrogate: dict[str, list], quick: bool = False,
          names: tuple[str, ...] = tuple(AGENT_QUANTITIES)) -> list[dict]:
    """The ``agent`` part: every quantity of :data:`AGENT_QUANTITIES` with fixed seeds."""
    kwargs: dict[str, Any] = {"runs_h0": 2, "steps_h0": 300, "runs_h1": 3} if quick else {}
    return [agent_quantity(name, surrogate, seed=31 + 10 * i, **kwargs) for i, name in enumerate(names)]


def allowance_study(allowance: float, target: float = 1e4, detectors: int = 32, seed: int = 1,
                    clip_sigma: float = 3.0, kind: str = "gce") -> dict[str, object]:
    """ARL at drifts inside/at/beyond the allowance and delays, for ``detectors`` learned nominals."""
    from edge_monitor.stats.calibration import calibrate
    from edge_monitor.stats.glr_batch import BatchWindowedGLR, MixtureBatch, clip_range, null_box, stack_bounds

    rng = np.random.default_rng(seed)
    nominals = [rng.standard_normal((60, 1)) for _ in range(detectors)]
    started = time.process_time()
    thresholds = np.array([calibrate(n, kind, 100, target, direction="increase", allowance=allowance,
                                     clip_sigma=clip_sigma).threshold for n in nominals])
    cpu = (time.process_time() - started) / detectors
    mixtures = MixtureBatch([fit_density(n, kind) for n in nominals])

    box = stack_bounds([null_box(n, "increase", allowance) for n in nominals])
    clip = stack_bounds([clip_range(n, clip_sigma) for n in nominals])

    def first_alarms(shift: float, steps: int) -> np.ndarray:
        glr = BatchWindowedGLR(mixtures, 100, 0.6, 1.0, "recursive", null_box=box, clip=clip)
        first = np.full(detectors, -1)
        for t in range(steps):
            crossed = (glr.update(rng.standard_normal((detectors, 1)) + shift) >= thresholds) & (first < 0)
            first[crossed] = t
        return first

    out: dict[str, object] = {"allowance": allowance, "target": target, "median_threshold": float(np.median(thresholds)),
                              "calibration_cpu_s": round(cpu, 2)}
    horizon = int(min(8 * target, 20_000))
    for shift in (0.0, 0.25, 0.5, 0.75):
        first = first_alarms(shift, horizon)
        alarms, exposure = int((first >= 0).sum()), int(np.where(first >= 0, first + 1, horizon).sum())
        out[f"arl_at_{shift}"] = exposure / alarms if alarms else f"> {exposure} (no alarm)"
        log.info("allowance %.2f: ARL at +%.2f σ %s", allowance, shift, out[f"arl_at_{shift}"])
    for shift in (1.0, 2.0, 3.0):
        first = first_alarms(shift, 400)
        out[f"median_delay_{shift}"] = float(np.median(np.where(first >= 0, first + 1, 400)))
    return out


def learning_error_study(n0: int, target: float = 1e4, detectors: int = 16, horizon: int = 5000, seed: int = 1,
                         kind: str = "gauss") -> dict[str, object]:
    """How the learning error spreads the run lengths of detectors calibrated at their learned nominal
    (the steady stage's calibration): ``detectors`` nominals of ``n0`` N(0, 1) values, each with its
    threshold for ``target``, run on N(0, 1) for ``horizon`` cycles. An exponential run length with mean
    ``target`` alarms within −ln 0.9 · target cycles with probability 10 %."""
    from edge_monitor.stats.calibration import calibrate
    from edge_monitor.stats.glr_batch import BatchWindowedGLR, MixtureBatch, clip_range, null_box, stack_bounds

    rng = np.random.default_rng(seed)
    nominals = [rng.standard_normal((n0, 1)) for _ in range(detectors)]
    thresholds = np.array([calibrate(n, kind, 100, target, direction="increase", allowance=0.75, clip_sigma=3.0,
                                     at="nominal").threshold for n in nominals])
    glr = BatchWindowedGLR(MixtureBatch([fit_density(n, kind) for n in nominals]), 100, 0.6, 1.0, "recursive",
                           null_box=stack_bounds([null_box(n, "increase", 0.75) for n in nominals]),
                           clip=stack_bounds([clip_range(n, 3.0) for n in nominals]))
    first = np.full(detectors, -1)
    for t in range(horizon):
        crossed = (glr.update(rng.standard_normal((detectors, 1))) >= thresholds) & (first < 0)
        first[crossed] = t + 1
    early = -math.log(0.9) * target
    alarms = int((first > 0).sum())
    exposure = int(np.where(first > 0, first, horizon).sum())
    return {"n0": n0, "kind": kind, "target": target, "thresholds": np.round(thresholds, 2).tolist(),
            "first_alarms": sorted(int(f) for f in first if f > 0), "horizon": horizon,
            "alarmed_within": {"cycles": round(early), "fraction": float(np.mean((first > 0) & (first <= early)))},
            "arl_estimate": exposure / alarms if alarms else None}


def simulated_quantities(seed: int, cycles: int, joints: int = 6, scenario: str | None = None,
                         motor_temperature: bool = True) -> dict[int, list[dict[str, float]]]:
    """Per joint, the detector inputs of every cycle after model learning (healthy, simulator defaults or
    the simulator ``scenario``: a file or packaged name), with the cycle's motor temperature [°C] as the
    controller reports it (``"motor_temperature"``; the detectors' thermal settling test watches it; a robot
    without one, ``motor_temperature=False``: the temperature read from the friction, which its detectors follow):
    studies.series, computed once per code version and kept in ``.cache/fleet_series``."""
    from studies.series import robot_series

    return robot_series(seed, cycles, joints, scenario, motor_temperature)


class _BoundaryShift:
    """Moves one detector's monitored values to the edge of its null hypothesis: + ``allowance`` ×
    the std of the values it learned, per input, in the units it watches (log for the KL distances),
    which is the least favourable healthy drift its threshold is calibrated for."""

    def __init__(self, bank: DetectorBank, inputs: tuple[str, ...]) -> None:
        from edge_monitor.features.registry import LOG_SCALE

        self.bank, self.inputs = bank, inputs
        self.allowance, self.n_nominal = bank.config.allowance, bank.config.n_nominal
        self.log = {q: bank.config.log_scale and q in LOG_SCALE for q in inputs}
        self.learned: list[list[float]] = []
        self.shift: dict[str, float] | None = None

    def watched(self, values: dict[str, float]) -> list[float]:
        watched = self.bank.watched(values)
        return [watched[q] for q in self.inputs]

    def __call__(self, values: dict[str, float], learning: bool) -> dict[str, float]:
        if learning:
            self.shift = None
            row = self.watched(values)
            if all(math.isfinite(x) for x in row):
                self.learned = (self.learned + [row])[-self.n_nominal:]
            return values
        if self.shift is None:
            spread = np.std(np.asarray(self.learned), axis=0, ddof=1) * self.allowance
            self.shift = dict(zip(self.inputs, spread.tolist()))
        return {q: (v * math.exp(self.shift[q]) if self.log[q] else v + self.shift[q]) if q in self.shift else v
                for q, v in values.items()}


def agent_arl(series: list[dict[int, list[dict[str, float]]]], target: float | tuple[float, ...],
              draws: int = 48, allowance: float | None = None, boundary: bool = False,
              calibrate_at: str | None = None, workers: int = 1, steady_at: str | None = None,
              steady_density: str | None = None, steady_transform: str | None = None,
              warm_up_alarm: str = "acknowledge") -> list[dict[str, object]]:
    """Measured ARL0 of the agent's detectors (shipped defaults, ``arl0_cycles = target``; several
    targets: rows for each) with renewal, one row per quantity and stage (``"warm-up"``: the nominal
    learned after commissioning; ``"steady"``: the one learned again once the motor temperature
    settled, what ``arl0_cycles`` is stated for); ``boundary``: each detector's monitored values moved
    to the edge of its null (:class:`_BoundaryShift`) and its threshold calibrated there;
    ``calibrate_at`` overrides ``decision.calibrate_at``, ``steady_at`` ``decision.steady_calibrate_at``. A warm-up
    alarm is followed by ``warm_up_alarm``: "reset" (relearn, as after a declared maintenance) or "acknowledge"
    (judged false: the statistic restarts on the same nominal, as in the steady stage). ``workers`` > 1: joints and
    targets run in that many processes."""
    if warm_up_alarm not in ("reset", "acknowledge"):
        raise ValueError(f"warm_up_alarm: expected 'reset' or 'acknowledge', got {warm_up_alarm!r}")
    from edge_monitor.pipeline.detectors import DecisionConfig

    targets = (target,) if isinstance(target, (int, float)) else tuple(target)
    extra: dict[str, Any] = {} if allowance is None else {"allowance": allowance}
    if boundary or calibrate_at:
        extra["calibrate_at"] = "boundary" if boundary else calibrate_at
    if boundary:               # the shift is defined for the first nominal only
        extra["steady_relearn"] = False
    if steady_at:
        extra["steady_calibrate_at"] = steady_at
    if steady_density:
        extra["steady_density"] = steady_density
    if steady_transform:
        extra["steady_transform"] = steady_transform
    tasks = [(rows, joint, t, draws, extra, boundary, warm_up_alarm) for t in targets for robot in series
             for joint, rows in robot.items()]
    if workers > 1:
        from concurrent.futures import ProcessPoolExecutor

        with ProcessPoolExecutor(workers) as pool:
            counts = list(pool.map(_joint_arl, *zip(*tasks)))
    else:
        counts = [_joint_arl(*task) for task in tasks]
    total: dict[tuple[float, str, str], list[int]] = {}
    for task, joint_counts in zip(tasks, counts):
        for (q, stage), numbers in joint_counts.items():
            acc = total.setdefault((task[2], q, stage), [0, 0, 0])
            acc[:] = [a + n for a, n in zip(acc, numbers)]
    calibrated_at = extra.get("calibrate_at", DecisionConfig().calibrate_at)
    steady_calibrated_at = extra.get("steady_calibrate_at", DecisionConfig().steady_calibrate_at)
    return [{"quantity": q, "stage": stage, "target_arl0": t,
             "measured_arl0": exposure / alarms if alarms else None, "monitored_cycles": exposure,
             "runs": runs, "false_alarms": alarms, "at_boundary": boundary,
             "calibrate_at": calibrated_at if stage == "warm-up" else steady_calibrated_at,
             "calibrated_ratio_95": calibrated_ratio_band(exposure / t)}
            for (t, q, stage), (exposure, alarms, runs) in sorted(total.items()) if exposure or runs]


def calibrated_ratio_band(expected: float) -> list[float | None]:
    """The central 95 % of measured / target ARL0 a detector calibrated exactly would show with ``expected`` alarms
    due, its alarms independent (Poisson; clustered alarms and joints of their own laws widen it): λ over the
    2.5 % and 97.5 % points of the count; None for an upper end where the 2.5 % point is no alarm."""
    if expected <= 0:
        return [None, None]
    low, high = (float(stats.poisson.ppf(q, expected)) for q in (0.025, 0.975))
    return [expected / high if high > 0 else None, expected / low if low > 0 else None]


def _joint_arl(rows: list[dict[str, float]], joint: int, target: float, draws: int, extra: dict[str, Any],
               boundary: bool, warm_up_alarm: str = "acknowledge") -> dict[tuple[str, str], tuple[int, int, int]]:
    """One joint's ``(quantity, stage) → (monitored cycles, false alarms, runs)`` (see :func:`agent_arl`)."""
    from edge_monitor.features.registry import QUANTITIES
    from edge_monitor.pipeline.detectors import DecisionConfig
    from studies.bank_replay import new_bank, replay_bank

    out: dict[tuple[str, str], tuple[int, int, int]] = {}
    for q in DecisionConfig().quantities:
        config = DecisionConfig(arl0_cycles=target, calibration_draws=draws, quantities=(q,), **extra)
        bank = new_bank(config)
        shift = _BoundaryShift(bank, QUANTITIES[q].inputs) if boundary else None
        counts = {"warm-up": [0, 0, 0], "steady": [0, 0, 0]}
        learning, stage = True, None

        def fed(values: dict[str, float]) -> dict[str, float]:
            """What this cycle feeds: at the edge of the null with ``boundary`` (read after the last step)."""
            return shift(values, learning) if shift is not None else values

        for step in replay_bank(bank, rows, joint, "r", fed):
            decision = step.decisions[q]
            now = str((decision.calibration or {}).get("stage", "warm-up"))
            if now != stage:                              # a new run: learning (again) or the steady nominal
                counts[now][2] += 1
            stage = now
            learning = decision.state != "monitoring"
            if decision.statistic is not None and decision.threshold is not None:    # a value was tested
                counts[now][0] += 1
            if decision.alarm:
                counts[now][1] += 1
                if now == "steady" or warm_up_alarm == "acknowledge":  # judged false: the statistic restarts
                    bank.detectors[q].acknowledge()       # on the same nominal (no cycles spent relearning)
                    counts[now][2] += 1
                else:                                     # as after a declared maintenance
                    bank.detectors[q].reset()
                    learning, stage = True, None
        out.update({(q, s): (c[0], c[1], c[2]) for s, c in counts.items()})
    return out


def _watched_series(bank: DetectorBank, rows: list[dict[str, float]], quantity: str) -> np.ndarray:
    """One joint's values of ``quantity`` (cycles × d) in the units its detector watches."""
    from edge_monitor.features.registry import QUANTITIES

    inputs = QUANTITIES[quantity].inputs
    return np.array([[w[q] for q in inputs] for w in map(bank.watched, rows)])


def _statistic_trace(values: np.ndarray, nominal: np.ndarray, config: DetectorConfig) -> np.ndarray:
    """Running maximum of the detector's statistic on ``values`` after learning ``nominal`` (no threshold)."""
    from edge_monitor.stats.glr_batch import BatchWindowedGLR, MixtureBatch, clip_range, null_box, stack_bounds

    glr = BatchWindowedGLR(MixtureBatch([fit_density(nominal, config.density)]), config.window, config.gamma0,
                           config.rho, "exact" if config.mode == "exact" else "recursive",
                           null_box=stack_bounds([null_box(nominal, config.direction, config.allowance)]),
                           clip=stack_bounds([clip_range(nominal, config.clip_sigma)]))
    return np.maximum.accumulate(np.array([glr.update(v[None, :])[0] for v in values]))


def real_run_lengths(series: list[np.ndarray], config: DetectorConfig, grid: np.ndarray) -> np.ndarray:
    """Measured mean run length at each threshold of ``grid`` on real series (one per joint): learn on
    ``n_nominal`` values, monitor to the first crossing, relearn after it; cycles / crossings."""
    exposure, alarms = np.zeros(grid.size), np.zeros(grid.size)
    for x in series:
        traces: dict[int, np.ndarray] = {}
        for i, h in enumerate(grid):
            start = 0
            while start + config.n_nominal < len(x):
                if start not in traces:
                    learn = start + config.n_nominal
                    traces[start] = _statistic_trace(x[learn:], x[start:learn], config)
                k = int(np.searchsorted(traces[start], h, side="left"))
                if k == len(traces[start]):
                    exposure[i] += k
                    break
                exposure[i] += k + 1
                alarms[i] += 1
                start += config.n_nominal + k + 1
    return np.where(alarms > 0, exposure / np.maximum(alarms, 1), np.inf)


def threshold_curves(series: list[dict[int, list[dict[str, float]]]], targets: tuple[float, ...],
                     draws: int = 32) -> list[dict[str, object]]:
    """Per quantity: thresholds for ``targets`` read off the healthy series themselves, and the median
    calibrated thresholds (learned nominal; allowance boundary) for the joints' first learned nominals."""
    from edge_monitor.pipeline.detectors import DecisionConfig, DetectorBank

    decision = DecisionConfig()
    bank = DetectorBank(decision, {})
    grid = np.arange(0.05, 30.0, 0.05)
    out = []
    for quantity in decision.quantities:
        config = decision.detector_config(quantity)
        joints = [_watched_series(bank, rows, quantity) for robot in series for rows in robot.values()]
        joints = [x[np.all(np.isfinite(x), axis=1)] for x in joints]
        real = real_run_lengths(joints, config, grid)
        row: dict[str, object] = {"quantity": quantity, "joints": len(joints),
                                  "real": {str(t): _first_reaching(grid, real, t) for t in targets}}
        for at in ("nominal", "boundary"):
            hs = np.array([[_calibrated(x[:config.n_nominal], config, t, draws, at) for t in targets] for x in joints])
            row[at] = {str(t): float(np.median(ok)) if (ok := hs[np.isfinite(hs[:, i]), i]).size else None
                       for i, t in enumerate(targets)}
            row[f"{at}_failed"] = int(np.isnan(hs).sum())     # calibrations that found too few alarms
        log.info("curves: %s done", quantity)
        out.append(row)
    return out


def _first_reaching(grid: np.ndarray, run_lengths: np.ndarray, target: float) -> float | None:
    reached = np.flatnonzero(run_lengths >= target)
    return float(grid[reached[0]]) if reached.size else None


def _calibrated(nominal: np.ndarray, config: DetectorConfig, target: float, draws: int, at: str) -> float:
    """The calibrated threshold for ``target`` of a detector that learned ``nominal``, simulated ``at``
    (NaN when the simulation found too few alarms; the agent then falls back to the asymptotic one)."""
    from edge_monitor.stats.calibration import CalibrationBudget, CalibrationError, calibrate

    try:
        return calibrate(nominal, config.density, config.window, target, config.gamma0, config.rho, "recursive",
                         CalibrationBudget(draws=draws), direction=config.direction, allowance=config.allowance,
                         clip_sigma=config.clip_sigma, at=at).threshold
    except CalibrationError:
        return math.nan


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--part", action="append", choices=("calibration", "power", "gce", "sequential", "agent",
                                                             "allowance", "learning"))
    parser.add_argument("--quick", action="store_true", help="small run counts (smoke test)")
    parser.add_argument("--agent", action="store_true", help="only the agent's detectors on simulator data "
                        "(see the module docstring)")
    parser.add_argument("--targets", default="50,200", help="--agent: target ARL0 values [cycles]")
    parser.add_argument("--robots", type=int, default=None, help="--agent: simulated robots (seeds 1 …)")
    parser.add_argument("--cycles", type=int, default=None, help="--agent: cycles per robot")
    parser.add_argument("--seeds", default=None, help="--agent: robot seeds instead of 1 … --robots, e.g. 101-108")
    parser.add_argument("--joints", type=int, default=None, help="--agent: joints per robot")
    parser.add_argument("--scenario", metavar="FILE.toml|NAME", default=None,
                        help="--agent: simulator scenario of every robot (e.g. plant_week; seeds, joints and "
                             "cycles as above)")
    parser.add_argument("--no-motor-temperature", action="store_true",
                        help="--agent: robots whose controller sends no motor temperature (their detectors follow "
                             "the temperature read from the friction, calibrated for their own warm-up law)")
    parser.add_argument("--allowance", type=float, default=None,
                        help="--agent: drift allowance [σ] instead of the shipped 0.75 (0: calibrated at Δ = 0)")
    parser.add_argument("--curves", action="store_true",
                        help="--agent: thresholds for the targets on the healthy series themselves against the "
                        "calibrated ones (learned nominal; allowance boundary); see the module docstring")
    parser.add_argument("--calibrate-at", choices=("healthy_drift", "boundary", "nominal"), default=None,
                        help="--agent: where the thresholds are calibrated instead of the shipped "
                        "decision.calibrate_at")
    parser.add_argument("--steady-at", choices=("boundary", "nominal"), default=None,
                        help="--agent: calibrate the steady nominal there instead of the shipped "
                             "decision.steady_calibrate_at")
    parser.add_argument("--steady-density", choices=("gauss", "kde", "gce"), default=None,
                        help="--agent: the steady nominal's density instead of decision.steady_density")
    parser.add_argument("--steady-transform", choices=("yeo-johnson", "none"), default=None,
                        help="--agent: the steady nominal's transform instead of decision.steady_transform")
    parser.add_argument("--warm-up-alarm", choices=("reset", "acknowledge"), default="acknowledge",
                        help="--agent: after a warm-up false alarm the detector restarts its statistic on the same "
                             "nominal (acknowledge, as the agent does; default) or relearns (reset, as after a "
                             "declared maintenance)")
    parser.add_argument("--at-boundary", action="store_true",
                        help="--agent: also measure with each detector's values moved to the edge of its null")
    parser.add_argument("--shape", default="gaussian", choices=sorted(SHAPES), help="sequential part: nominal shape")
    parser.add_argument("--density", default="gce", choices=("gauss", "kde", "gce"))
    parser.add_argument("--calibration-densities", default="gauss,kde,gce")
    parser.add_argument("--calibration-shapes", default="gaussian,skewed,bimodal")
    parser.add_argument("--seed", type=int, default=2026)
    parser.add_argument("--fit-from", type=Path, help="agent part: fit the surrogate to this symptoms JSONL "
                        "(joint --joint) instead of the built-in SURROGATE fit")
    parser.add_argument("--joint", type=int, default=0, help="joint for --fit-from")
    parser.add_argument("--quantities", default=",".join(AGENT_QUANTITIES), help="agent part: which detectors")
    parser.add_argument("--allowances", default="0,0.75", help="allowance part: allowances [σ] to study")
    parser.add_argument("--json", type=Path, help="write all results here")
    args = parser.parse_args(argv)
    logging.basicConfig(level=logging.INFO, format="%(asctime)s %(message)s", datefmt="%H:%M:%S")
    logging.getLogger("edge_monitor").setLevel(logging.ERROR)  # thousands of expected H0 alarms
    if args.agent:
        return _agent_main(args)
    parts = args.part or ["calibration", "power", "gce", "sequential", "agent", "allowance"]
    q = args.quick
    results: dict[str, object] = {}
    if "gce" in parts:
        results["gce"] = gce_quality(args.seed)
    if "calibration" in parts:
        results["calibration"] = calibration(200, 10 if q else 60, 20 if q else 80, 200 if q else 500, args.seed,
                                             tuple(args.calibration_densities.split(",")),
                                             shapes=tuple(args.calibration_shapes.split(",")))
    if "power" in parts:
        results["power"] = power(200, 10 if q else 50, 20 if q else 40, args.seed)
    if "sequential" in parts:
        results["sequential"] = (sequential(args.shape, 2, 300, 5, density=args.density) if q
                                 else sequential(args.shape, density=args.density))
    if "agent" in parts:
        surrogate = fit_surrogate(args.fit_from, args.joint) if args.fit_from else SURROGATE
        results["agent"] = {"surrogate": surrogate,
                            "quantities": agent(surrogate, q, tuple(args.quantities.split(",")))}
    if "learning" in parts:
        results["learning"] = [learning_error_study(n0, detectors=8 if q else 16, horizon=1000 if q else 5000,
                                                    kind=kind) for kind in ("gauss", "gce") for n0 in (60, 240)]
    if "allowance" in parts:
        target = 200.0 if q else 1e4
        results["allowance"] = [allowance_study(float(a), target, detectors=8 if q else 32)
                                for a in args.allowances.split(",")]
    text = json.dumps(results, indent=1)
    print(text)
    if args.json:
        args.json.write_text(text)
    return 0


def _agent_main(args: argparse.Namespace) -> int:
    robots = args.robots or (2 if args.quick else 4)
    cycles = args.cycles or (1600 if args.quick else 2000)
    joints, draws = (2, 48) if args.quick else (6, 48)
    workers = max(1, min(os.cpu_count() or 1, 8))
    started = time.monotonic()
    if args.scenario:
        from sim_controller.scenario import scenario_config
        try:
            scenario_config(args.scenario, {"joints": joints, "cycles": cycles})
        except ValueError as exc:          # ScenarioError / SimConfigError: names the field
            print(f"arl_study: {exc}", file=sys.stderr)
            return 2
    seeds = None
    if args.seeds:
        from studies.settings import parse_seeds

        seeds = parse_seeds(args.seeds)
        robots = len(seeds)
    if args.joints:
        joints = args.joints
    series = _simulate_robots(robots, cycles, joints, workers, args.scenario, seeds, not args.no_motor_temperature)
    if args.curves:
        targets = tuple(float(t) for t in args.targets.split(","))
        return _print_json({"robots": robots, "joints": joints, "cycles": cycles, "scenario": args.scenario,
                            "calibration_draws": 32,
                            "rows": threshold_curves(series, targets)}, args.json)
    targets = tuple(float(t) for t in args.targets.split(","))
    log.info("simulated %d robots × %d joints × %d cycles in %.0f s; running the detectors", robots, joints,
             cycles, time.monotonic() - started)
    rows = agent_arl(series, targets, draws, args.allowance, calibrate_at=args.calibrate_at, workers=workers,
                     steady_at=args.steady_at, steady_density=args.steady_density,
                     steady_transform=args.steady_transform, warm_up_alarm=args.warm_up_alarm)
    if args.at_boundary:
        rows += agent_arl(series, targets, draws, args.allowance, boundary=True, workers=workers)
    log.info("detectors done, %.0f s", time.monotonic() - started)
    steady = [r for r in rows if r["stage"] == "steady" and not r["at_boundary"]]
    return _print_json({"robots": robots, "joints": joints, "cycles": cycles, "scenario": args.scenario,
                        "motor_temperature": not args.no_motor_temperature,
                        "calibration_draws": draws, "allowance": args.allowance, "calibrate_at": args.calibrate_at,
                        "steady_at": args.steady_at, "steady_density": args.steady_density,
                        "steady_transform": args.steady_transform, "warm_up_alarm": args.warm_up_alarm,
                        "rows": steady,
                        "other_rows": [r for r in rows if r not in steady]}, args.json)


def _simulate_robots(robots: int, cycles: int, joints: int, workers: int, scenario: str | None = None,
                     seeds: list[int] | None = None,
                     motor_temperature: bool = True) -> list[dict[int, list[dict[str, float]]]]:
    """:func:`simulated_quantities` of ``seeds`` (default 1 … ``robots``), in up to ``workers`` processes."""
    seeds = seeds or list(range(1, robots + 1))
    robots = len(seeds)
    if workers < 2 or robots < 2:
        return [simulated_quantities(seed, cycles, joints, scenario, motor_temperature) for seed in seeds]
    from concurrent.futures import ProcessPoolExecutor

    with ProcessPoolExecutor(min(workers, robots)) as pool:
        return list(pool.map(simulated_quantities, seeds, [cycles] * robots, [joints] * robots,
                             [scenario] * robots, [motor_temperature] * robots))


def _print_json(result: dict[str, object], path: Path | None) -> int:
    text = json.dumps(result, indent=1)
    print(text)
    if path:
        path.write_text(text)
    return 0


if __name__ == "__main__":
    sys.exit(main())
