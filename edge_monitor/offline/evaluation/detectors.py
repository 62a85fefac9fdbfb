"""The detectors an evaluation compares and how each reads its test quantity q from the agent's symptoms.

Every value comes from the agent's own per-cycle output (no second implementation): the wear feature's
record, the KL feature's record and torque densities, and the friction curve it extracted. The §7
baselines (:mod:`edge_monitor.offline.baselines`) learn their nominal model from the agent's output on
the nominal (learning) cycles.
"""

from __future__ import annotations

import math
from typing import Callable, Sequence

from edge_monitor.offline.baselines import (
    BaselineError,
    SpeedOnlyNominal,
    data_likelihood,
    distribution_peak,
    fit_speed_only_nominal,
)
from edge_monitor.records import Symptom

#: Detector name → what q is (for reports).
DETECTORS: dict[str, str] = {
    "wear": "wear estimate ϖ̂ (maximum likelihood, the record's wear.estimate)",
    "wear_score": "wear score (signed root of the likelihood ratio against no wear; what the agent's detector watches)",
    "kl_raw": "KL distance of the cycle's torque density to nominal (kl.raw)",
    "kl_weighted": "KL distance with disturbance-rejecting speed weights (kl.weighted)",
    "param_change": "parameter change (Hotelling T²) of the speed-only friction model (§7 baseline)",
    "dist_peak": "distribution peak 1 − 1/(√(2π)·σ̂) of the cycle's torque density (§7 baseline)",
    "data_likelihood": "mean negative log nominal density of the cycle's torque samples (§7 baseline)",
}


class DetectorError(ValueError):
    """Unknown detector name."""


def select_detectors(names: Sequence[str]) -> list[str]:
    """The named detectors, checked (unknown names refused with the list of known ones)."""
    for name in names:
        if name not in DETECTORS:
            raise DetectorError(f"unknown detector {name!r}; known detectors: {', '.join(DETECTORS)}")
    if len(set(names)) != len(names):
        raise DetectorError(f"detector names repeat: {', '.join(names)}")
    if not names:
        raise DetectorError("no detector selected")
    return list(names)


def _number(value: object) -> float:
    return float(value) if isinstance(value, (int, float)) and math.isfinite(value) else math.nan


def _density(symptom: Symptom, key: str) -> object:
    density = symptom.extras.get("density") or {}
    return density.get(key)


class Readout:
    """Per-cycle q of every selected detector; the baselines' nominal models from the nominal cycles."""

    def __init__(self, detectors: Sequence[str], nominal: Sequence[Symptom]) -> None:
        self.detectors = list(detectors)
        self.param_nominal: SpeedOnlyNominal | None = None
        if "param_change" in self.detectors:
            curves = [(s.friction["speeds"], s.friction["torque"]) for s in nominal if s.friction.get("speeds")]
            try:
                self.param_nominal = fit_speed_only_nominal(curves)
            except BaselineError:
                self.param_nominal = None       # its q is NaN; the runner reports it
        self._read: dict[str, Callable[[Symptom], float]] = {
            "wear": lambda s: _number(s.sections.get("wear", {}).get("estimate")),
            "wear_score": lambda s: _number(s.sections.get("wear", {}).get("score")),
            "kl_raw": lambda s: _number(s.sections.get("kl", {}).get("raw")),
            "kl_weighted": lambda s: _number(s.sections.get("kl", {}).get("weighted")),
            "param_change": self._param_change,
            "dist_peak": self._peak,
            "data_likelihood": self._likelihood,
        }

    def values(self, symptom: Symptom) -> dict[str, float]:
        """q of one test cycle per detector (NaN where the agent had no value)."""
        return {name: self._read[name](symptom) for name in self.detectors}

    def _param_change(self, s: Symptom) -> float:
        if self.param_nominal is None or not s.friction.get("speeds"):
            return math.nan
        return self.param_nominal.chi2(s.friction["speeds"], s.friction["torque"])

    def _peak(self, s: Symptom) -> float:
        grid, cycle = _density(s, "grid"), _density(s, "cycle")
        return math.nan if grid is None or cycle is None else distribution_peak(grid, cycle)  # type: ignore[arg-type]

    def _likelihood(self, s: Symptom) -> float:
        grid, cycle, nominal = _density(s, "grid"), _density(s, "cycle"), _density(s, "nominal")
        if grid is None or cycle is None or nominal is None:
            return math.nan
        return data_likelihood(grid, cycle, nominal)  # type: ignore[arg-type]
