"""Average performance (SNR) and effective scope of a detector, by Monte Carlo on its surrogate (§8).

Both compare H0 (fault at f0) with H1 (fault at f0 + Δ) under random disturbances d ~ N(0, σ²) in
coded units. q = surrogate(f, d) + ε with ε ~ N(0, ``noise_std``²): the spread of the q a threshold
test actually sees at fixed factor levels (the runner's choice: one cycle's q by default, see
:mod:`.runner`). Without it (``noise_std = 0``) a surrogate with no disturbance effect would be
perfectly separable at any Δ > 0.

* :func:`snr`: ``(μ1 − μ0)/σ1`` with every disturbance random at once; defaults f0 = −0.5, Δ = 1,
  σ = 0.25 (coded), 10⁵ draws.
* :func:`scope_matrix`: one disturbance at a time (the others at 0), over a grid of Δ ∈ [0, 4] and
  σ ∈ [0.01, 1] (30 × 30); a cell is in scope when the one-sided threshold test at Pf = 0.01 (the
  H0 quantile, on the side the fault moves q) detects H1 with Pd ≥ 0.99. Here f0 = −2 (no wear), so
  Δ = 4 is the top of the fault range. The same standard-normal draws serve every cell (common random
  numbers: the matrix is smooth and reproducible).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from edge_monitor.offline.evaluation.surrogate import Surrogate

SNR_F0, SNR_DELTA, SNR_SIGMA, SNR_DRAWS = -0.5, 1.0, 0.25, 100_000
SCOPE_F0, SCOPE_PF, SCOPE_PD = -2.0, 0.01, 0.99
SCOPE_DELTAS = np.linspace(0.0, 4.0, 30)
SCOPE_SIGMAS = np.linspace(0.01, 1.0, 30)


def snr(model: Surrogate, f0: float = SNR_F0, delta: float = SNR_DELTA, sigma: float = SNR_SIGMA,
        draws: int = SNR_DRAWS, noise_std: float = 0.0, seed: int = 0) -> float:
    """SNR ``(μ1 − μ0)/σ1`` of q between f = f0 and f = f0 + Δ, disturbances ~ N(0, σ²I) (coded)."""
    rng = np.random.default_rng(seed)
    n = len(model.factors)
    noise = noise_std if math.isfinite(noise_std) else 0.0
    d = sigma * rng.standard_normal((draws, n - 1))
    z0 = np.column_stack([np.full(draws, f0), d])
    z1 = np.column_stack([np.full(draws, f0 + delta), d])
    q0 = model.predict(z0) + noise * rng.standard_normal(draws)
    q1 = model.predict(z1) + noise * rng.standard_normal(draws)
    spread = float(q1.std())
    return float((q1.mean() - q0.mean()) / spread) if spread > 0 else math.copysign(math.inf, q1.mean() - q0.mean())


def _slice(model: Surrogate, k: int) -> tuple[float, float, float, float, float, float]:
    """Coefficients of q(f, d_k) with the other disturbances at 0: c, a·f, g·f², b·d, e·f·d, h·d²."""
    eta = dict(zip(model.terms, model.theta))
    f, d = model.factors[0], model.factors[k]
    return (eta["1"], eta[f], eta[f"{f}^2"], eta[d], eta[f"{f}*{d}"], eta[f"{d}^2"])


@dataclass(frozen=True)
class Scope:
    """Scope matrix of one detector and disturbance: ``inside[i, j]`` for σ = ``sigmas[i]``, Δ = ``deltas[j]``."""

    disturbance: str
    deltas: NDArray[np.float64]
    sigmas: NDArray[np.float64]
    inside: NDArray[np.bool_]

    def min_delta(self) -> list[float | None]:
        """Per σ: the smallest Δ in scope (coded), None when no Δ of the grid is."""
        return [float(self.deltas[np.argmax(row)]) if row.any() else None for row in self.inside]

    def max_sigma(self) -> float | None:
        """Where the scope ends: the largest σ at which some Δ ≤ max Δ is in scope (None: nowhere)."""
        rows = np.flatnonzero(self.inside.any(axis=1))
        return float(self.sigmas[rows[-1]]) if rows.size else None

    def min_delta_at(self, sigma: float) -> float | None:
        """Smallest Δ in scope at the grid σ nearest ``sigma``."""
        return self.min_delta()[int(np.argmin(np.abs(self.sigmas - sigma)))]

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready (the grids are the evaluation's, see its settings); ``inside``: one string per σ
        (ascending), "1" where that Δ (ascending) is in scope."""
        return {"disturbance": self.disturbance,
                "inside": ["".join("1" if x else "0" for x in row) for row in self.inside],
                "min_delta": self.min_delta(), "max_sigma": self.max_sigma(),
                "fraction_inside": float(self.inside.mean())}


def scope_matrix(model: Surrogate, k: int, deltas: NDArray[np.float64] = SCOPE_DELTAS,
                 sigmas: NDArray[np.float64] = SCOPE_SIGMAS, f0: float = SCOPE_F0, pf: float = SCOPE_PF,
                 pd: float = SCOPE_PD, draws: int = 20_000, noise_std: float = 0.0, seed: int = 0) -> Scope:
    """Scope matrix of disturbance ``k`` (index into ``model.factors``, ≥ 1); see the module docstring."""
    if not 1 <= k < len(model.factors):
        raise ValueError(f"scope_matrix: disturbance index {k} not in 1 … {len(model.factors) - 1}")
    c, a, g, b, e, h = _slice(model, k)
    rng = np.random.default_rng(seed)
    u = rng.standard_normal(draws)
    noise = noise_std if math.isfinite(noise_std) else 0.0
    eps0, eps1 = noise * rng.standard_normal(draws), noise * rng.standard_normal(draws)
    f1 = f0 + np.asarray(deltas, dtype=float)
    inside = np.zeros((len(sigmas), len(deltas)), dtype=bool)
    for i, sigma in enumerate(sigmas):
        d = sigma * u
        q0 = c + a * f0 + g * f0 ** 2 + (b + e * f0) * d + h * d ** 2 + eps0
        lo, hi = np.quantile(q0, [pf, 1.0 - pf])
        q1 = (c + a * f1 + g * f1 ** 2)[:, None] + (b + e * f1)[:, None] * d[None, :] + h * d[None, :] ** 2 \
            + eps1[None, :]
        up = q1.mean(axis=1) >= q0.mean()
        detected = np.where(up, (q1 > hi).mean(axis=1), (q1 < lo).mean(axis=1))
        inside[i] = detected >= pd
    return Scope(model.factors[k], np.asarray(deltas, dtype=float), np.asarray(sigmas, dtype=float), inside)
