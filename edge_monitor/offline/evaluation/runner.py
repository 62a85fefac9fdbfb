"""The evaluation from end to end: every design and validation point simulated in parallel processes,
then per detector the surrogate, its validation fit, normalised coefficients, SNR and scope matrices.

The surrogate models the expected q (the mean over a point's test cycles). The Monte Carlo of SNR and
scope adds the spread of the q a threshold test decides on (``noise``):

* ``"cycle"`` (default): one cycle's q, as the agent's detectors see it — the pooled within-point
  std s_w of the per-cycle values plus any lack of fit beyond the noise of a T-cycle mean:
  ``√(s_w² + max(0, γ̂ − s_w²/T))``;
* ``"mean"``: the mean of T test cycles: ``√γ̂`` (the surrogate's residual std);
* ``"none"``: the surrogate alone.

:func:`run_evaluation` returns the JSON-ready result (``evaluation.json``; :mod:`.report` draws and
writes it). Progress: a tqdm bar on a terminal, and an INFO status line at most every
``STATUS_EVERY_S`` seconds (``-v``).
"""

from __future__ import annotations

import logging
import math
import multiprocessing
import os
import signal
import time
from dataclasses import dataclass, replace
from typing import Any

import numpy as np
from numpy.typing import NDArray

from edge_monitor.config import AgentConfig
from edge_monitor.offline.evaluation import scope as sc
from edge_monitor.offline.evaluation.detectors import DETECTORS
from edge_monitor.offline.evaluation.factors import Factor
from edge_monitor.offline.evaluation.simulate import PointResult, PointSpec, run_point
from edge_monitor.offline.evaluation.surrogate import fit_surrogate, validation_fit
from edge_monitor.records import finite_or_none, to_strict
from protocol.console import progress_bar, terminate_like_interrupt

log = logging.getLogger(__name__)

#: Seconds between status lines.
STATUS_EVERY_S = 30.0


def default_jobs() -> int:
    """min(2, CPUs): the machines this runs on are small and shared."""
    return max(1, min(2, os.cpu_count() or 1))


@dataclass(frozen=True)
class Settings:
    """Everything an evaluation depends on (coded designs: rows = runs, columns = ``factors``)."""

    factors: tuple[Factor, ...]
    detectors: tuple[str, ...]
    agent: AgentConfig
    design: NDArray[np.float64]
    validation: NDArray[np.float64]
    joint: int = 0
    joints: int = 6
    seed: int = 1
    test_cycles: int = 20
    jobs: int = 1
    snr_draws: int = sc.SNR_DRAWS
    scope_draws: int = 20_000
    noise: str = "cycle"
    design_name: str = "central composite"

    def specs(self) -> list[PointSpec]:
        rows = np.vstack([self.design, self.validation])
        return [PointSpec(index=i, coded=tuple(float(c) for c in row), factors=self.factors,
                          detectors=self.detectors, agent=self.agent, joint=self.joint, joints=self.joints,
                          seed=self.seed, test_cycles=self.test_cycles) for i, row in enumerate(rows)]

    def describe(self) -> dict[str, Any]:
        spec = self.specs()[0] if len(self.design) else None
        return {
            "factors": [{"name": f.name, "label": f.label, "unit": f.unit, "low": f.low, "high": f.high,
                         "unit_step": f.unit_step} for f in self.factors],
            "detectors": {d: DETECTORS[d] for d in self.detectors},
            "joint": self.joint, "joints": self.joints, "seed": self.seed, "test_cycles": self.test_cycles,
            "nominal_cycles": spec.nominal_cycles if spec else None, "design_runs": len(self.design),
            "design_name": self.design_name,
            "validation_runs": len(self.validation), "jobs": self.jobs, "noise": self.noise,
            "snr": {"f0": sc.SNR_F0, "delta": sc.SNR_DELTA, "sigma": sc.SNR_SIGMA, "draws": self.snr_draws},
            "scope": {"f0": sc.SCOPE_F0, "pf": sc.SCOPE_PF, "pd": sc.SCOPE_PD, "draws": self.scope_draws,
                      "deltas": [float(sc.SCOPE_DELTAS[0]), float(sc.SCOPE_DELTAS[-1]), len(sc.SCOPE_DELTAS)],
                      "sigmas": [float(sc.SCOPE_SIGMAS[0]), float(sc.SCOPE_SIGMAS[-1]), len(sc.SCOPE_SIGMAS)]},
        }


def simulate_points(specs: list[PointSpec], jobs: int, progress: bool = True) -> list[PointResult]:
    """Run every point (in ``jobs`` worker processes when > 1), in index order."""
    results: dict[int, PointResult] = {}
    started = last = time.monotonic()
    with progress_bar(len(specs), "evaluate: design points", enabled=progress, unit="point") as bar:
        def done(result: PointResult) -> None:
            nonlocal last
            results[result.index] = result
            bar.update(1)
            now = time.monotonic()
            if now - last >= STATUS_EVERY_S or len(results) == len(specs):
                last = now
                log.info("evaluate: %d/%d design points simulated, %.0f s", len(results), len(specs), now - started)

        with terminate_like_interrupt():
            if jobs <= 1:
                for spec in specs:
                    done(run_point(spec))
            else:
                pool = multiprocessing.get_context().Pool(jobs, initializer=_ignore_sigint)
                try:
                    for result in pool.imap_unordered(run_point, specs):
                        done(result)
                except BaseException:
                    pool.terminate()        # drop the queued points, end the workers now
                    pool.join()
                    raise
                pool.close()
                pool.join()
    return [results[i] for i in sorted(results)]


def _ignore_sigint() -> None:
    """Workers leave Ctrl-C (sent to the whole process group) to the parent, which terminates them;
    that SIGTERM ends a worker silently (the default action), not through the parent's handler that a
    forked worker would otherwise inherit from :func:`protocol.console.terminate_like_interrupt` (a traceback
    per worker)."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    signal.signal(signal.SIGTERM, signal.SIG_DFL)


def noise_std(settings: Settings, gamma: float, cycle_std: list[float]) -> dict[str, float]:
    """Spread of q per the ``noise`` choice (see the module docstring): the per-cycle, mean and used std."""
    s2 = np.asarray(cycle_std, dtype=float) ** 2
    within = float(np.nanmean(s2)) if np.isfinite(s2).any() else 0.0
    gamma = gamma if math.isfinite(gamma) else 0.0
    per_cycle = math.sqrt(within + max(0.0, gamma - within / settings.test_cycles))
    used = {"cycle": per_cycle, "mean": math.sqrt(gamma), "none": 0.0}[settings.noise]
    return {"cycle": per_cycle, "within_cycle": math.sqrt(within), "mean": math.sqrt(gamma), "used": used}


def analyse(settings: Settings, points: list[PointResult]) -> dict[str, Any]:
    """Surrogates, validation fits, normalised coefficients, SNR and scope per detector."""
    n_design = len(settings.design)
    names = tuple(f.name for f in settings.factors)
    out: dict[str, Any] = {}
    for k, det in enumerate(settings.detectors):
        q = np.array([p.q[det] for p in points])
        model = fit_surrogate(settings.design, q[:n_design], names)
        fit = validation_fit(model, settings.validation, q[n_design:]) if len(settings.validation) else math.nan
        seed = settings.seed * 1000 + k
        noise = noise_std(settings, model.gamma, [p.q_std[det] for p in points[:n_design]])
        scopes = {names[i]: sc.scope_matrix(model, i, draws=settings.scope_draws, noise_std=noise["used"],
                                            seed=seed) for i in range(1, len(names))}
        dominant, significant = model.dominant()
        step = settings.factors[0].unit_step
        out[det] = {
            "surrogate": model.to_dict(),
            "validation_fit": finite_or_none(fit),
            "noise": noise,
            "snr": finite_or_none(sc.snr(model, draws=settings.snr_draws, noise_std=noise["used"], seed=seed)),
            "dominant_disturbance": dominant,
            "dominant_significant": significant,
            "runner_up": model.runner_up(),
            "scope": {d: s.to_dict() for d, s in scopes.items()},
            "min_fault_at_default_sigma": {d: (None if (m := s.min_delta_at(sc.SNR_SIGMA)) is None else m * step)
                                           for d, s in scopes.items()},
        }
    ranking = sorted(out, key=lambda d: -abs(out[d]["snr"] or 0.0))
    return {"detectors": out, "ranking_by_snr": ranking}


def run_evaluation(settings: Settings, progress: bool = True) -> dict[str, Any]:
    """Simulate and analyse (see the module docstring); the JSON of all numbers."""
    started = time.monotonic()
    points = simulate_points(settings.specs(), settings.jobs, progress)
    missing = {d: [p.index for p in points if not math.isfinite(p.q[d])] for d in settings.detectors}
    for det, where in missing.items():
        if where:
            log.warning("evaluate: detector %s has no value at points %s; it is left out", det, where)
    usable = tuple(d for d in settings.detectors if not missing[d])
    analysed = Settings(**{**settings.__dict__, "detectors": usable})
    simulated = time.monotonic() - started
    result = {"settings": settings.describe(), "design": settings.design.tolist(),
              "validation_design": settings.validation.tolist(), "points": [p.to_dict() for p in points],
              **analyse(analysed, points), "left_out": {d: w for d, w in missing.items() if w},
              "seconds": {"simulation": simulated, "total": time.monotonic() - started}}
    strict: dict[str, Any] = to_strict(result)
    return strict


def run_replicated(settings: Settings, seeds: int, progress: bool = True) -> dict[str, Any]:
    """:func:`run_evaluation` for ``seeds`` seeds (``settings.seed`` … ``settings.seed + seeds − 1``: another
    simulated robot and other test cycles each). Every table is of the first seed; ``replication`` holds,
    per detector, the SNR and the disturbance influences of every seed with their mean and range, and
    the dominant disturbance per seed, so that single-seed findings can be told from robust ones."""
    first = run_evaluation(settings, progress)
    runs = [first] + [run_evaluation(replace(settings, seed=settings.seed + k), progress) for k in range(1, seeds)]
    first["replication"] = replication(runs)
    first["seconds"]["total_replicated"] = sum(r["seconds"]["total"] for r in runs)
    return first


def _spread(values: list[float | None]) -> dict[str, Any]:
    finite = [v for v in values if v is not None and math.isfinite(v)]
    return {"per_seed": values, "mean": float(np.mean(finite)) if finite else None,
            "min": min(finite) if finite else None, "max": max(finite) if finite else None}


def replication(runs: list[dict[str, Any]]) -> dict[str, Any]:
    """Per detector (those of every run): SNR, influences and dominant disturbance across the runs' seeds."""
    dets = [d for d in runs[0]["detectors"] if all(d in r["detectors"] for r in runs)]
    out: dict[str, Any] = {"seeds": [r["settings"]["seed"] for r in runs], "detectors": {}}
    for d in dets:
        entries = [r["detectors"][d] for r in runs]
        dists = list(entries[0]["surrogate"]["influence"])
        out["detectors"][d] = {
            "snr": _spread([e["snr"] for e in entries]),
            "influence": {x: _spread([e["surrogate"]["influence"][x] for e in entries]) for x in dists},
            "dominant_disturbance": [e["dominant_disturbance"] for e in entries],
        }
    out["best_snr"] = [r["ranking_by_snr"][0] if r["ranking_by_snr"] else None for r in runs]
    return out
