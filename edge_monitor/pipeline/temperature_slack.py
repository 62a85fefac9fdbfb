"""The temperature slack of a detector: how far a healthy joint's watched values drift while its temperature is
outside the span its nominal was learned in, learned per joint as it visits those temperatures
(docs/DETECTION.md, "Watching while the joint warms").

The KL distances' temperature compensation leaves a drift that grows with the distance d [°C] from the
nominal's span, fast over the first few °C and slowly after, and that differs a lot from joint to joint (on
healthy default robots the log KL distances of most joints drift 0.05 … 0.3 σ/√°C, a few up to 0.65 σ/√°C, so
+2.8 σ at 20 °C above the span). One number cannot serve them all: a slack wide enough for the few leaves the
many blind, one for the many makes the few alarm. So each detector learns its joint's own law while the joint
warms, per axis (input) z = a·√d + e, z the value in standard deviations of the nominal, e ~ N(0, 1):

* a Bayesian line through the origin with the fleet's law as prior, a ~ N(ā, s²) (``[decision.temperature_slack]``),
  updated each tested cycle outside the span (regressor x = √d: precision 1/s² + Σ x², mean (ā/s² + Σ x·z)/precision);
* one cycle's pull is bounded: its innovation z − â·√d is clipped to ±:data:`HUBER` before it enters, so a
  wear step is not learned at once (a slow drift is: the price of learning while watching, which the wear
  score, compensated through the friction model and with no slack, does not pay);
* the detector tests its value less the slack (â + :data:`MARGIN_SDS`·sd(â))·x, never below 0, per axis; no
  learning while an alarm is latched;
* the steady nominal, learned warm, keeps the warm-up's law: the KL distances are still measured against the
  reference density of the joint's first cycles, so a steady joint d₁ °C above its warm-up span whose steady
  nominal lies d₀ above it has drifted a·(√d₁ − √d₀) further, not a·√(d₁ − d₀) (the law is flat there): the
  regressor on the warm side becomes √d₁ − √d₀, and the law goes on learning from it.

Warm side (hotter than the span: warming up, a hot day) and cold side (colder: after a stop) are learned apart;
a new nominal (the steady one, or after a maintenance) starts again from the prior. Memory: two numbers per
axis and side. Units: d in °C, z and the slack in nominal standard deviations, a in σ/√°C.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np
from numpy.typing import ArrayLike

#: The largest innovation [nominal std] one cycle brings into the learned law.
HUBER = 2.0
#: The slack is the learned law plus this many of its standard deviations.
MARGIN_SDS = 2.0
#: Sides of the span a law is learned for.
SIDES = ("warm", "cold")


class SlackLaw:
    """The law z = a·√d of one side of one detector, per axis: ``update(d, z)``, ``slack(d)``."""

    def __init__(self, prior: Sequence[tuple[float, float]]) -> None:
        self.prior = [(float(m), float(s)) for m, s in prior]
        self.precision = np.array([1.0 / (s * s) if s > 0 else math.inf for _, s in self.prior])
        self.weighted = np.array([m / (s * s) if s > 0 else 0.0 for m, s in self.prior])

    @property
    def mean(self) -> np.ndarray:
        """â per axis [σ/√°C] (an axis with a zero prior spread keeps its prior mean)."""
        fixed = np.array([m for m, _ in self.prior])
        with np.errstate(invalid="ignore"):
            learned = self.weighted / self.precision
        return np.where(np.isinf(self.precision), fixed, learned)

    @property
    def sd(self) -> np.ndarray:
        """Standard deviation of â per axis [σ/√°C]."""
        return 1.0 / np.sqrt(self.precision)

    def slack(self, x: float) -> np.ndarray:
        """The slack at regressor ``x`` [√°C] (√d outside the span): (â + MARGIN_SDS·sd)·x per axis [nominal std],
        never below 0 (a law that says the values fall does not make the detector stricter)."""
        return np.maximum(0.0, (self.mean + MARGIN_SDS * self.sd) * max(x, 0.0))

    def update(self, x: float, z: ArrayLike) -> None:
        """One tested cycle at regressor ``x`` > 0 [√°C] with axis values ``z`` [nominal std] (non-finite axes
        are skipped)."""
        if not (math.isfinite(x) and x > 0):
            return
        values = np.asarray(z, dtype=float)
        innovation = np.clip(values - self.mean * x, -HUBER, HUBER)
        learn = np.isfinite(values) & np.isfinite(self.precision)
        self.weighted = np.where(learn, self.weighted + x * (self.mean * x + innovation), self.weighted)
        self.precision = np.where(learn, self.precision + x * x, self.precision)

    def state_dict(self) -> dict[str, Any]:
        return {"precision": [_finite(p) for p in self.precision], "weighted": self.weighted.tolist()}

    def load_state(self, state: Any) -> None:
        """From :meth:`state_dict`; anything unusable leaves the prior."""
        if not isinstance(state, dict):
            return
        precision, weighted = state.get("precision"), state.get("weighted")
        if not (isinstance(precision, list) and isinstance(weighted, list)
                and len(precision) == len(weighted) == len(self.prior)):
            return
        p = np.array([math.inf if v is None else v for v in precision], dtype=float)
        w = np.asarray(weighted, dtype=float)
        if np.all((p > 0) & ~np.isnan(p)) and np.all(np.isfinite(w)):
            self.precision, self.weighted = p, w


class SlackProfile:
    """Both sides' laws of one detector (see the module docstring)."""

    def __init__(self, prior: Sequence[tuple[float, float]]) -> None:
        self.laws = {side: SlackLaw(prior) for side in SIDES}

    def slack(self, side: str, x: float) -> tuple[float, ...] | None:
        """The slack per axis [nominal std] at regressor ``x`` on ``side``; None where it is 0 on every axis."""
        if x <= 0:
            return None
        out = tuple(float(v) for v in self.laws[side].slack(x))
        return out if any(out) else None

    def update(self, side: str, x: float, z: ArrayLike) -> None:
        if x > 0:
            self.laws[side].update(x, z)

    def state_dict(self) -> dict[str, Any]:
        return {side: law.state_dict() for side, law in self.laws.items()}

    @classmethod
    def from_state(cls, prior: Sequence[tuple[float, float]], state: Any) -> "SlackProfile":
        out = cls(prior)
        for side, law in out.laws.items():
            law.load_state(state.get(side) if isinstance(state, dict) else None)
        return out


def prior_for(inputs: Sequence[str], priors: Mapping[str, tuple[float, float]]) -> list[tuple[float, float]]:
    """The prior (mean, sd) [σ/√°C] of each input (no drift where none is stated)."""
    return [priors.get(name, (0.0, 0.0)) for name in inputs]


def standardized(value: ArrayLike, mean: ArrayLike, spread: ArrayLike) -> np.ndarray:
    """A detector's value in standard deviations of its nominal, per axis."""
    return (np.asarray(value, dtype=float) - np.asarray(mean, dtype=float)) / np.asarray(spread, dtype=float)


def _finite(x: float) -> float | None:
    return float(x) if math.isfinite(x) else None
