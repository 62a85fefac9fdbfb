"""Second-order surrogate model of a detector's test quantity q over the coded factors z (§8).

``q ≈ φ(z)ᵀθ`` with φ = [1, z_i, z_i·z_j (i < j), z_i²] (:func:`~.design.quadratic_terms`), fitted by
least squares on the design; covariance ``γ̂·(ΦᵀΦ)⁻¹`` with ``γ̂ = ‖q − Φθ̂‖²/(N − p)`` (p coefficients;
the spec's N − n − 1 with n the non-constant terms). Validation fit on other points:
``100·(1 − ‖ε‖²/‖q − mean(q)‖²)`` [%]. Normalised coefficients ``η/η0``: every coefficient divided by
the fault's own main effect η0 (the fault is factor 0); |η/η0| > 1 means that term moves q more than
one coded unit of fault does.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, Sequence

import numpy as np
from numpy.typing import ArrayLike, NDArray

from edge_monitor.offline.evaluation.design import DesignError, check_estimable, quadratic_matrix, quadratic_terms
from edge_monitor.records import finite_or_none


@dataclass(frozen=True)
class Surrogate:
    """A fitted second-order model: factor names, term names, θ̂, its covariance and γ̂ (q units²)."""

    factors: tuple[str, ...]
    terms: tuple[str, ...]
    theta: NDArray[np.float64]
    cov: NDArray[np.float64]
    gamma: float
    runs: int

    def predict(self, z: ArrayLike) -> NDArray[np.float64]:
        """q at coded points ``z`` (rows; one column per factor)."""
        return quadratic_matrix(np.atleast_2d(np.asarray(z, dtype=float))) @ self.theta

    @property
    def residual_std(self) -> float:
        """√γ̂: spread of q about the model at a design point (noise and lack of fit), NaN without dof."""
        return math.sqrt(self.gamma) if math.isfinite(self.gamma) else math.nan

    @property
    def fault_effect(self) -> float:
        """η0: the fault's main-effect coefficient (change of q per coded unit of fault at z = 0)."""
        return float(self.theta[1])

    def normalised(self) -> dict[str, float]:
        """``η/η0`` of every term except the constant and the fault's main effect (NaN when η0 = 0)."""
        eta0 = self.fault_effect
        return {t: (float(c) / eta0 if eta0 != 0 else math.nan)
                for t, c in zip(self.terms, self.theta) if t not in ("1", self.factors[0])}

    def influence(self) -> dict[str, float]:
        """Per disturbance: max(|η_d|, |η_dd|)/|η0|, the larger of its main and square effect relative to the
        fault's main effect (how strongly it moves q on its own)."""
        eta = dict(zip(self.terms, self.theta))
        eta0 = abs(self.fault_effect)
        return {d: (max(abs(eta[d]), abs(eta[f"{d}^2"])) / eta0 if eta0 > 0 else math.inf)
                for d in self.factors[1:]}

    def standard_errors(self) -> NDArray[np.float64]:
        return np.sqrt(np.clip(np.diag(self.cov), 0.0, None))

    def ranked(self) -> list[str]:
        """The disturbances, largest :meth:`influence` first."""
        influence = self.influence()
        return sorted(influence, key=lambda x: -influence[x])

    def _larger_term(self, d: str) -> int:
        index = {t: i for i, t in enumerate(self.terms)}
        return max(index[d], index[f"{d}^2"], key=lambda i: abs(self.theta[i]))

    def dominant(self) -> tuple[str | None, bool | None]:
        """The disturbance of largest :meth:`influence`, and whether it is significantly larger than the
        runner-up's: |θ_a| − |θ_b| of their larger terms (main or square) exceeds twice the standard error
        of that difference, from the coefficient covariance (with a single disturbance: |θ_a| > 2 SE).
        False: the ranking is within the noise of the fit; None: not testable (no residual dof)."""
        ranked = self.ranked()
        if not ranked:
            return None, False
        d = ranked[0]
        if not math.isfinite(self.gamma):
            return d, None
        a = self._larger_term(d)
        ta = float(self.theta[a])
        if len(ranked) == 1:
            se = float(self.standard_errors()[a])
            return d, abs(ta) > 2.0 * se
        b = self._larger_term(ranked[1])
        tb = float(self.theta[b])
        sa, sb = math.copysign(1.0, ta), math.copysign(1.0, tb)
        if self.cov.shape == (len(self.theta), len(self.theta)):
            var = float(self.cov[a, a] + self.cov[b, b] - 2.0 * sa * sb * self.cov[a, b])
            se_diff = math.sqrt(max(var, 0.0))
        else:                                       # no covariance: the conservative sum of the SEs
            ses = self.standard_errors()
            se_diff = float(ses[a] + ses[b])
        return d, abs(ta) - abs(tb) > 2.0 * se_diff

    def runner_up(self) -> str | None:
        """The disturbance of second-largest :meth:`influence` (None with fewer than two)."""
        ranked = self.ranked()
        return ranked[1] if len(ranked) > 1 else None

    def to_dict(self) -> dict[str, Any]:
        se = self.standard_errors()
        return {"terms": list(self.terms), "coefficients": self.theta.tolist(), "std_errors": se.tolist(),
                "gamma": finite_or_none(self.gamma), "residual_std": finite_or_none(self.residual_std),
                "runs": self.runs, "fault_effect": self.fault_effect,
                "normalised": {k: finite_or_none(v) for k, v in self.normalised().items()},
                "influence": {k: finite_or_none(v) for k, v in self.influence().items()}}


def fit_surrogate(design: ArrayLike, q: ArrayLike, factors: Sequence[str]) -> Surrogate:
    """Least-squares fit of the second-order model to ``q`` (one value per design row)."""
    z = np.atleast_2d(np.asarray(design, dtype=float))
    y = np.asarray(q, dtype=float)
    if z.shape[1] != len(factors):
        raise DesignError(f"design has {z.shape[1]} columns for {len(factors)} factors")
    if y.shape != (z.shape[0],):
        raise DesignError(f"need one q per design run: {y.size} values for {z.shape[0]} runs")
    if not np.all(np.isfinite(y)):
        raise DesignError(f"q is missing (NaN) at runs {np.flatnonzero(~np.isfinite(y)).tolist()}")
    check_estimable(z)
    phi = quadratic_matrix(z)
    theta, *_ = np.linalg.lstsq(phi, y, rcond=None)
    n, p = phi.shape
    dof = n - p
    gamma = float(np.sum((y - phi @ theta) ** 2) / dof) if dof > 0 else math.nan
    cov = np.asarray((gamma if dof > 0 else 0.0) * np.linalg.pinv(phi.T @ phi), dtype=np.float64)
    return Surrogate(tuple(factors), tuple(quadratic_terms(list(factors))), theta, cov, gamma, n)


def validation_fit(model: Surrogate, design: ArrayLike, q: ArrayLike) -> float:
    """``100·(1 − ‖q − q̂‖²/‖q − mean(q)‖²)`` [%] on validation points (NaN with fewer than 2 points)."""
    y = np.asarray(q, dtype=float)
    if y.size < 2:
        return math.nan
    resid = y - model.predict(design)
    spread = float(np.sum((y - y.mean()) ** 2))
    return 100.0 * (1.0 - float(np.sum(resid ** 2)) / spread) if spread > 0 else math.nan
