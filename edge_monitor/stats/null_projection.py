"""The shift of H0 closest to an estimate, in the nominal's own metric (docs/ALGORITHMS.md §6).

A detector with a drift allowance tests "the shift left the box ``lower ≤ Δ ≤ upper``". Its GLR
compares the estimate Δ̂ with the box point H0 explains the data best with: for a Gaussian nominal
N(μ, S) the point ``Δc`` minimising ``(Δ̂ − Δc)ᵀ S⁻¹ (Δ̂ − Δc)`` over the box (a small quadratic
programme). In one dimension it is ``clip(Δ̂, lower, upper)``. In several, clipping each axis on its
own is not: with two correlated axes and a shift along only one of them (the other inside its
allowance), H0 can move the other axis along the correlation and explain most of the shift, while the
clipped point leaves it where it was and overstates the evidence by up to 1/(1 − ρ²). That is how a
load step that moved log kl_weighted by 0.5–0.8 σ and log kl_raw (ρ ≈ 0.6–0.9) by little raised the
joint vector's statistic to 2–3× that of its neighbours (docs/DETECTION.md, "Operating conditions").

:func:`box_projection` solves the programme exactly for many small problems at once by enumerating
the active sets (each axis free, at its lower or at its upper bound: 3^d candidates, 2^d with one open
side; d ≤ 3 here): for a fixed set A at values v, the free axes F follow from
``r_F = −(P_FF)⁻¹ P_FA r_A`` with ``r = Δ̂ − Δc``, ``r_A = Δ̂_A − v``, P = S⁻¹; the feasible candidate
of least ``rᵀPr`` is the minimum (the objective is convex and the optimum is one of the candidates).
tests/test_null_projection.py checks it against ``scipy.optimize.lsq_linear``.
"""

from __future__ import annotations

import itertools

import numpy as np
from numpy.typing import NDArray

#: Slack of the feasibility test of a candidate [units of the bounds' scale]: rounding only.
_FEASIBLE_RTOL = 1e-9

#: Kinds of an axis in an active set.
_FREE, _LOWER, _UPPER = 0, 1, 2


def box_projection(delta: NDArray[np.float64], lower: NDArray[np.float64], upper: NDArray[np.float64],
                   precision: NDArray[np.float64]) -> NDArray[np.float64]:
    """argmin over ``lower ≤ x ≤ upper`` of ``(Δ − x)ᵀ P (Δ − x)``, for every row: ``delta`` (B, A, d),
    bounds (B, d), ``precision`` (B, d, d) (see :class:`BoxProjector`)."""
    return BoxProjector(lower, upper, precision)(delta)


class BoxProjector:
    """The closest box point in each detector's metric, for B detectors with fixed bounds and metric.

    ``lower``, ``upper``: (B, d) bounds (±inf for an open side; lower ≤ 0 ≤ upper); ``precision``:
    (B, d, d) symmetric positive definite. The free axes' response to the fixed ones,
    ``−(P_FF)⁻¹ P_FA``, is computed once per active set and detector; a call then runs plain 1-d array
    arithmetic over the estimates outside their boxes (no per-estimate matrix products): for each
    active set the candidate point, and the first that satisfies the optimality conditions (feasible,
    multipliers of the right sign: ``(P·r)_i ≥ 0`` at an upper bound, ``≤ 0`` at a lower one) is the
    optimum.
    """

    def __init__(self, lower: NDArray[np.float64], upper: NDArray[np.float64], precision: NDArray[np.float64]) -> None:
        self.lower, self.upper = np.asarray(lower, dtype=float), np.asarray(upper, dtype=float)
        self.precision = np.asarray(precision, dtype=float)
        self.dim = d = self.lower.shape[1]
        finite = {_LOWER: np.isfinite(self.lower).any(axis=0), _UPPER: np.isfinite(self.upper).any(axis=0)}
        scale = np.where(np.isfinite(self.lower), np.abs(self.lower), 0.0) + \
            np.where(np.isfinite(self.upper), np.abs(self.upper), 0.0)
        self.slack = _FEASIBLE_RTOL * (1.0 + scale)
        self.sets: list[tuple[tuple[int, ...], NDArray[np.int64], NDArray[np.int64], NDArray[np.float64]]] = []
        for kinds in itertools.product((_FREE, _LOWER, _UPPER), repeat=d):
            kinds_a = np.asarray(kinds)
            fixed, free = np.flatnonzero(kinds_a != _FREE), np.flatnonzero(kinds_a == _FREE)
            if fixed.size == 0 or any(not finite[int(kinds_a[a])][a] for a in fixed):
                continue                  # Δ itself (inside the box only), or a bound no detector has
            response = np.zeros((len(self.lower), free.size, fixed.size))
            if free.size:
                p_ff = self.precision[:, free[:, None], free[None, :]]
                p_fa = self.precision[:, free[:, None], fixed[None, :]]
                response = -np.linalg.solve(p_ff, p_fa)
            self.sets.append((kinds, fixed, free, response))
        self._by_code = {sum(k * 3**i for i, k in enumerate(item[0])): item for item in self.sets}

    def __call__(self, delta: NDArray[np.float64]) -> NDArray[np.float64]:
        """``delta`` (B, A, d) → the closest box points (B, A, d); rows inside the box as they are."""
        lo, hi = self.lower[:, None, :], self.upper[:, None, :]
        clipped = np.clip(delta, lo, hi)
        if self.dim == 1:
            return clipped
        rows, cols = np.nonzero(np.any(clipped != delta, axis=-1))
        if rows.size:
            clipped[rows, cols] = self._solve(delta[rows, cols], rows)
        return clipped

    def _solve(self, delta: NDArray[np.float64], rows: NDArray[np.int64]) -> NDArray[np.float64]:
        """The optimum for M estimates (M, d) of detectors ``rows`` (M,), all outside their boxes: first
        the active set of the axes that are outside (the optimum for most estimates), then every set
        for the rest."""
        lower, upper = self.lower[rows], self.upper[rows]
        out = np.clip(delta, lower, upper)            # where no set qualifies (rounding at a degenerate point)
        kinds_of = np.where(delta > upper, _UPPER, np.where(delta < lower, _LOWER, _FREE))
        code = kinds_of @ (3 ** np.arange(self.dim))
        todo = np.ones(rows.size, dtype=bool)
        for c in np.unique(code):
            if int(c) in self._by_code:
                sub = np.flatnonzero(code == c)
                todo[sub[self._try(self._by_code[int(c)], delta, rows, sub, out)]] = False
        rest = np.flatnonzero(todo)
        for active_set in self.sets:
            if rest.size == 0:
                break
            rest = rest[~self._try(active_set, delta, rows, rest, out)]
        return out

    def _try(self, active_set: tuple[tuple[int, ...], NDArray[np.int64], NDArray[np.int64], NDArray[np.float64]],
             delta: NDArray[np.float64], rows: NDArray[np.int64], sub: NDArray[np.int64],
             out: NDArray[np.float64]) -> NDArray[np.bool_]:
        """The candidate of ``active_set`` for the estimates ``sub`` (indices into ``delta``/``rows``);
        where it is the optimum (feasible, multipliers of the right sign) it goes into ``out``. The mask."""
        kinds, fixed, free, response = active_set
        d, det = self.dim, rows[sub]
        est = [delta[sub, i] for i in range(d)]
        lo = [self.lower[det, i] for i in range(d)]
        hi = [self.upper[det, i] for i in range(d)]
        slack = [self.slack[det, i] for i in range(d)]
        r: list[NDArray[np.float64]] = [np.zeros(0)] * d
        ok = np.ones(sub.size, dtype=bool)
        for a in fixed:
            bound = lo[a] if kinds[a] == _LOWER else hi[a]
            ok &= np.isfinite(bound)
            r[a] = est[a] - np.where(np.isfinite(bound), bound, 0.0)
        for k, f in enumerate(free):
            r[f] = sum(response[det, k, m] * r[a] for m, a in enumerate(fixed))
        x = [est[i] - r[i] for i in range(d)]
        for i in range(d):
            ok &= (x[i] >= lo[i] - slack[i]) & (x[i] <= hi[i] + slack[i])
        for a in fixed:               # the multipliers: H0 pushes against the bound it sits on
            pr = sum(self.precision[det, a, j] * r[j] for j in range(d))
            ok &= (pr >= -slack[a]) if kinds[a] == _UPPER else (pr <= slack[a])
        if ok.any():
            out[sub[ok]] = np.clip(np.stack([v[ok] for v in x], axis=1), self.lower[det[ok]], self.upper[det[ok]])
        return ok


def covariance_precision(covariance: NDArray[np.float64]) -> NDArray[np.float64]:
    """P = S⁻¹ of (B, d, d) covariances (symmetrised against rounding)."""
    p = np.linalg.inv(covariance)
    return 0.5 * (p + p.transpose(0, 2, 1))
