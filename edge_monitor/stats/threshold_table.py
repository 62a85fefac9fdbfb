"""Thresholds of one-dimensional Gaussian detectors at the shipped settings, computed once with a large
simulation and shipped with the package (``edge_monitor/stats/data/gaussian_thresholds.json``).

In standard units a scalar Gaussian detector's threshold depends only on its settings
(:mod:`edge_monitor.stats.gaussian_calibration`), so every such detector of every joint needs the same
number. ``tools/threshold_table.py`` computes it for the shipped warm-up and steady settings over
ARL0 = 10^1.5 … 10^7 with its bootstrap standard error; :func:`lookup` interpolates in log ARL0
(a detector with other settings, or a target outside the table, is simulated at run time).
"""

from __future__ import annotations

import functools
import json
import math
from dataclasses import asdict
from importlib import resources
from typing import Any

import numpy as np

from edge_monitor.stats.gaussian_calibration import GaussianSettings, GaussianThreshold

#: The table's file inside the package.
RESOURCE = "gaussian_thresholds.json"


def key(settings: GaussianSettings) -> str:
    """The table key of ``settings`` (exact values: a table holds only what was computed)."""
    return json.dumps({k: list(v) if isinstance(v, tuple) else v for k, v in asdict(settings).items()},
                      sort_keys=True)


@functools.lru_cache(maxsize=1)
def _table() -> dict[str, dict[str, Any]]:
    try:
        text = resources.files("edge_monitor.stats").joinpath("data", RESOURCE).read_text(encoding="utf-8")
    except (FileNotFoundError, OSError):
        return {}
    out = {}
    for e in json.loads(text).get("entries", []):
        per_axis = {name: tuple(e["settings"].get(name, ())) for name in ("drift_mean", "drift_sd", "wander")}
        out[key(GaussianSettings(**{**e["settings"], **per_axis}))] = e
    return out


def lookup(settings: GaussianSettings, arl0: float) -> GaussianThreshold | None:
    """The tabulated threshold for ``arl0`` (interpolated in log ARL0), or None if not tabulated."""
    entry = _table().get(key(settings))
    if entry is None:
        return None
    targets = np.log(np.asarray(entry["arl0"], dtype=float))
    target = math.log(float(arl0))
    if not targets[0] <= target <= targets[-1]:
        return None
    h = float(np.interp(target, targets, entry["threshold"]))
    h_se = float(np.interp(target, targets, entry["h_se"]))
    return GaussianThreshold(h, h_se, float(arl0), "table", int(entry["events_min"]), int(entry["detectors"]),
                             int(entry["steps"]), 0.0)
