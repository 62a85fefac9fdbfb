"""Thresholds of Gaussian detectors at the shipped settings, computed once with a large simulation and
shipped with the package (``edge_monitor/stats/data/gaussian_thresholds.json``).

In standard units a Gaussian detector's threshold depends only on its settings and, for a vector, on
the correlation matrix R of its learned values (:mod:`edge_monitor.stats.gaussian_calibration`).

* **Scalars** (d = 1): every detector of every joint with the same settings needs the same number.
* **The joint vector** (d = 3: wear score, log kl_raw, log kl_weighted): tabulated over the correlation
  ρ of its two KL axes (:data:`VECTOR_AXES`), which on healthy joints is 0.3–0.9 and lowers the
  threshold (H0's nearest point can follow a shift along the correlation), with the wear axis
  uncorrelated; :func:`lookup` interpolates linearly in ρ between the tabulated values and clamps
  outside them (ρ below the lowest tabulated value reads that value's larger, cautious threshold).
  The wear score's correlations with the KL axes (−0.4 … +0.3 on healthy joints) move the threshold
  far less than its standard error (docs/DETECTION.md, "Thresholds").

``tools/studies/threshold_table.py`` computes the entries over ARL0 = 10^1.5 … 10^7 with their bootstrap
standard errors; :func:`lookup` interpolates in log ARL0 (a detector with other settings, or a target
outside the table, is simulated at run time).
"""

from __future__ import annotations

import functools
import json
import math
from dataclasses import asdict
from importlib import resources
from typing import Any

import numpy as np

from edge_monitor.stats.gaussian_calibration import Correlation, GaussianSettings, GaussianThreshold

#: The table's file inside the package.
RESOURCE = "gaussian_thresholds.json"
#: Settings that enter a key only when set (the entries computed before they existed keep their keys).
OPTIONAL_FIELDS = ("spread_mean", "spread_sd", "skew")
#: The pair of axes of a vector detector whose correlation indexes the table.
VECTOR_AXES = (1, 2)


def key(settings: GaussianSettings, dim: int = 1) -> str:
    """The table key of ``settings`` for a ``dim``-dimensional detector (exact values: a table holds only
    what was computed)."""
    fields = {k: list(v) if isinstance(v, tuple) else v for k, v in asdict(settings).items()
              if not (k in OPTIONAL_FIELDS and v == ())}
    return json.dumps({**fields, **({"dim": dim} if dim > 1 else {})}, sort_keys=True)


def tabulated_correlation(rho: float, dim: int) -> Correlation:
    """The correlation matrix a ``dim``-dimensional table entry is computed for: ρ between
    :data:`VECTOR_AXES`, 0 elsewhere."""
    r = np.eye(dim)
    if dim > 1:
        i, j = VECTOR_AXES
        r[i, j] = r[j, i] = rho
    return tuple(tuple(float(x) for x in row) for row in r)


def entry_settings(entry: dict[str, Any]) -> GaussianSettings:
    """The settings of a table entry (its JSON lists as tuples)."""
    fields: dict[str, Any] = {k: tuple(v) if isinstance(v, list) else v for k, v in entry["settings"].items()}
    return GaussianSettings(**fields)


def entry_correlation(entry: dict[str, Any]) -> Correlation:
    """The correlation matrix a table entry was computed for (((1.0,),) for a scalar)."""
    return tuple(tuple(float(x) for x in row) for row in (entry.get("correlation") or [[1.0]]))


def correlation_rho(corr: Correlation) -> float:
    """ρ between :data:`VECTOR_AXES` of a correlation matrix (0 for a scalar)."""
    i, j = VECTOR_AXES
    return float(corr[i][j]) if len(corr) > 1 else 0.0


def entry_rho(entry: dict[str, Any]) -> float:
    """ρ between :data:`VECTOR_AXES` of a table entry (0 for a scalar)."""
    return correlation_rho(entry_correlation(entry))


@functools.lru_cache(maxsize=1)
def entries_by_key() -> dict[str, list[dict[str, Any]]]:
    """The shipped table: key (:func:`key`) → the entries of that key, sorted by ρ. Read once per process
    (``entries_by_key.cache_clear()`` reads it again)."""
    try:
        text = resources.files("edge_monitor.stats").joinpath("data", RESOURCE).read_text(encoding="utf-8")
    except (FileNotFoundError, OSError):
        return {}
    out: dict[str, list[dict[str, Any]]] = {}
    for e in json.loads(text).get("entries", []):
        out.setdefault(key(entry_settings(e), len(entry_correlation(e))), []).append(e)
    for entries in out.values():
        entries.sort(key=entry_rho)
    return out


def _read(entry: dict[str, Any], target: float) -> tuple[float, float] | None:
    """(h, h_se) of one entry at log ARL0 ``target``, or None outside its range."""
    targets = np.log(np.asarray(entry["arl0"], dtype=float))
    if not targets[0] <= target <= targets[-1]:
        return None
    return (float(np.interp(target, targets, entry["threshold"])),
            float(np.interp(target, targets, entry["h_se"])))


def lookup(settings: GaussianSettings, arl0: float, corr: Correlation = ((1.0,),)) -> GaussianThreshold | None:
    """The tabulated threshold for ``arl0`` (interpolated in log ARL0 and, for a vector, in ρ of
    :data:`VECTOR_AXES`), or None if not tabulated."""
    dim = len(corr)
    entries = entries_by_key().get(key(settings, dim))
    if not entries:
        return None
    target = math.log(float(arl0))
    rhos = [entry_rho(e) for e in entries]
    given = correlation_rho(corr)
    if not math.isfinite(given):
        return None
    rho = min(max(given, rhos[0]), rhos[-1])
    k = max(0, int(np.searchsorted(rhos, rho, side="right")) - 1)
    m = min(k + 1, len(entries) - 1)                   # the entries either side of ρ (the same at an end)
    below, above = entries[k], entries[m]
    read_below, read_above = _read(below, target), _read(above, target)
    if read_below is None or read_above is None:
        return None
    w = (rho - rhos[k]) / (rhos[m] - rhos[k]) if rhos[m] > rhos[k] else 0.0
    h, h_se = ((1.0 - w) * a + w * b for a, b in zip(read_below, read_above))
    events = min(int(below["events_min"]), int(above["events_min"]))
    return GaussianThreshold(h, h_se, float(arl0), "table", events, int(below["detectors"]), int(below["steps"]), 0.0)
