"""Where the prognosis's error comes from (docs/PROGNOSIS.md, "Where it fails"): the agent's trend model
replayed on the same wearing joints with seven inputs, from the agent's to an ideal one, scored with the
metrics of :mod:`studies.prognosis_metrics`:

* ``agent``              the agent's wear estimates (its learned friction model, nominal wear coefficients);
* ``posterior_mean``     the agent's posterior means of the wear instead of its estimates (the modes), with
                         the same std (the posterior's, which is taken about the mean);
* ``shuffled_in_bins``   the true wear plus the agent's own errors (estimate − truth), permuted in time
                         within bins of 2.5 wear units: the errors' size and wear-dependent bias kept, their
                         correlation over time broken;
* ``shuffled``           the same errors permuted over the whole life: only their distribution kept;
* ``known_model``        the estimates of the same agent given each joint's true friction model (the
                         simulator's individually varied parameters, wear coefficients included; kept by
                         :mod:`studies.prognosis_series` as kind ``known_model``, with its own alarms);
* ``wear_coefficients``  the true wear as an unbiased estimator with the *nominal* wear coefficients reads
                         it (:func:`nominal_equivalent`), plus Gaussian noise of the agent's stated std:
                         what the ±8 % individual variation of the wear coefficients alone costs;
* ``truth``              the true wear plus that noise: the trend model's own error.

The four synthetic inputs (``shuffled_in_bins``, ``shuffled``, ``wear_coefficients``, ``truth``) keep the
agent's alarms, stds and skipped cycles, so they differ from ``agent`` only in the estimates' errors.
"""

from __future__ import annotations

import dataclasses
import math
from typing import Any, Sequence

import numpy as np
from scipy.optimize import minimize_scalar

from joint_model import FrictionParams
from joint_model.friction import DEFAULT_PARAMS, wear_friction
from sim_controller.config import DEFAULT_SPEEDS
from studies.prognosis_fleet import CycleRow

VARIANTS = ("agent", "posterior_mean", "known_model", "shuffled_in_bins", "shuffled", "wear_coefficients", "truth")
#: Width of the true-wear bins within which ``shuffled_in_bins`` permutes the errors.
SHUFFLE_BIN = 2.5
#: True wear grid [wear units] on which the nominal equivalent is computed (interpolated between).
_WEAR_GRID = np.arange(0.0, 80.0001, 0.5)
#: The laws a local linear trend covers (its rate constant between changes): α–λ is judged on these.
STRAIGHT_LAWS = ("linear", "step_ramp", "rate_change")
#: Band of true wear in which the estimates' bias is reported (where α–λ is judged).
BIAS_BAND = (10.0, 30.0)


def nominal_equivalent(joint: FrictionParams, nominal: FrictionParams = DEFAULT_PARAMS,
                       speeds: Sequence[float] = DEFAULT_SPEEDS) -> tuple[np.ndarray, np.ndarray]:
    """(true wear grid, the wear whose friction under the ``nominal`` wear coefficients best matches the
    joint's wear friction at the test cycle's ``speeds``, equal weights): what an unbiased estimator that
    knows everything but the joint's own wear coefficients reads."""
    v = np.abs(np.asarray(speeds, dtype=float))
    out = np.empty_like(_WEAR_GRID)
    for i, w in enumerate(_WEAR_GRID):
        target = wear_friction(v, w, joint)
        fit = minimize_scalar(lambda x, t=target: float(np.sum((wear_friction(v, x, nominal) - t) ** 2)),
                              bounds=(0.0, 2.0 * _WEAR_GRID[-1]), method="bounded", options={"xatol": 1e-4})
        out[i] = float(fit.x) if w > 0 else 0.0
    return _WEAR_GRID.copy(), out


def synthetic_rows(rows: Sequence[CycleRow], reading: tuple[np.ndarray, np.ndarray] | None,
                   rng: np.random.Generator) -> list[CycleRow]:
    """``rows`` with each estimate replaced by the true wear read through ``reading`` ((grid, values); None:
    the truth) plus N(0, std²) noise, std the row's own; rows without an estimate keep none."""
    out = []
    for r in rows:
        if r.estimate is None or r.std is None or not math.isfinite(r.wear):
            out.append(r)
            continue
        level = r.wear if reading is None else float(np.interp(r.wear, reading[0], reading[1]))
        out.append(dataclasses.replace(r, estimate=max(0.0, level + float(r.std) * float(rng.standard_normal()))))
    return out


def shuffled_rows(rows: Sequence[CycleRow], rng: np.random.Generator, bin_width: float | None) -> list[CycleRow]:
    """``rows`` with their errors (estimate − true wear) permuted among the rows that have an estimate: within
    bins of ``bin_width`` true wear, or over all of them (None); estimates stay ≥ 0."""
    kept = [k for k, r in enumerate(rows) if r.estimate is not None and math.isfinite(r.wear)]
    errors = np.array([float(rows[k].estimate or 0.0) - rows[k].wear for k in kept])
    wear = np.array([rows[k].wear for k in kept])
    groups = np.zeros(wear.size) if bin_width is None else np.floor(wear / bin_width)
    permuted = errors.copy()
    for g in np.unique(groups):
        members = np.flatnonzero(groups == g)
        permuted[members] = errors[rng.permutation(members)]
    out = list(rows)
    for k, e in zip(kept, permuted):
        out[k] = dataclasses.replace(rows[k], estimate=max(0.0, rows[k].wear + float(e)))
    return out


def posterior_mean_rows(rows: Sequence[CycleRow]) -> list[CycleRow]:
    """``rows`` with each estimate replaced by the row's posterior mean (rows without one keep none)."""
    return [dataclasses.replace(r, estimate=r.posterior_mean if r.estimate is not None else None) for r in rows]


def bias_in_band(rows: Sequence[CycleRow], band: tuple[float, float] = BIAS_BAND) -> float | None:
    """Mean of estimate − true wear over the complete, learned cycles whose true wear lies in ``band``."""
    errors = [r.estimate - r.wear for r in rows if r.estimate is not None and not (r.learning or r.partial)
              and band[0] <= r.wear <= band[1]]
    return float(np.mean(errors)) if errors else None


def joint_summary(law: str, joint: int, seed: int, scores: dict[str, list[Any]], biases: dict[str, float | None],
                  reading_at_critical: float) -> dict[str, Any]:
    """One joint's line of the per-joint table (per input, the share of its noise draws whose median at λ
    is within ±α; the bias per real input)."""
    return {"seed": seed, "joint": joint, "law": law,
            "alpha_lambda": {k: float(np.mean([bool(s.alpha_lambda) for s in v])) for k, v in scores.items()},
            "bias": biases, "nominal_reading_at_critical": reading_at_critical}
