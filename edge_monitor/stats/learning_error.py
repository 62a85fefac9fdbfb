"""The learning error of a Gaussian nominal, drawn from its exact law by importance sampling
(docs/ALGORITHMS.md, "the learning error integrated by importance sampling").

A nominal learned from N0 independent values of N(0, R) has a known law: for d = 1 the fitted mean's
error √N0·μ̂ ~ N(0, 1) and the spread (N0 − 1)·σ̂² ~ χ²(N0 − 1); for d > 1 the whitened mean
√N0·L⁻¹μ̂ ~ N(0, I) (R = L·Lᵀ) and (N0 − 1)·Σ̂ ~ Wishart(N0 − 1, R), mean and spread independent. A
detector calibrated at the allowance boundary alarms most on the few nominals learned too low and too
narrow, which plain draws of a few thousand learning sets hardly hold; so the calibration
(:mod:`edge_monitor.stats.gaussian_calibration`) draws the fits from a deterministic mixture of
proposals tilted there and weights each by prior over mixture density (the balance heuristic: the
weights are at most the number of proposals, mean 1).
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import NDArray
from scipy.stats import gamma, norm

#: Importance sampling of a nominal's learning error (:func:`scalar_fits`, :func:`vector_fits`): a
#: deterministic mixture of proposals, each tilting the fitted mean down and its spread narrower by this
#: many standard deviations of their own errors, along :data:`TILT_DIRECTION` — where the warm-up
#: detector's false alarms come from.
TILTS = (0.0, 1.5, 3.0, 4.5)
#: (fitted mean, log fitted spread): the direction in which a learning error moves the boundary's stream
#: furthest above the learned box, in units of each error's standard deviation, (1/√N0, 1/√(2(N0 − 1))):
#: the shift δ = (a − μ̂)/σ̂ − a at the allowance a = 0.75 moves 1 : 0.75·σ_logσ̂/σ_μ̂ ≈ 1 : 0.55.
TILT_DIRECTION = (0.875, 0.485)


def scalar_fits(n0: int, index: NDArray[np.int64], rng: np.random.Generator
                ) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]:
    """Fitted means (G, 1) and variances (G, 1, 1) of scalar nominals learned from ``n0`` independent
    standard normal values, drawn by importance sampling, and their weights (G,), mean 1.

    Nominal g is drawn from proposal ``index[g] mod len(TILTS)`` (a deterministic mixture): the fitted
    mean's error u = √N0·μ̂ from N(−t·c_u, 1), the spread's q = (N0 − 1)·σ̂² from χ²(N0 − 1) scaled by
    exp(−2·t·c_s·σ_logσ̂) (log σ̂ moved t·c_s of its standard deviations), t the tilt, (c_u, c_s)
    :data:`TILT_DIRECTION`; its weight is the exact density over the mixture's (balance heuristic)."""
    k = (n0 - 1) / 2.0                                       # χ²(N0 − 1) = Gamma(k, scale 2)
    sd_log_sd = 1.0 / math.sqrt(2.0 * (n0 - 1))
    tilt = np.asarray(TILTS)
    mean_shift = -tilt * TILT_DIRECTION[0]
    scale = 2.0 * np.exp(-2.0 * tilt * TILT_DIRECTION[1] * sd_log_sd)
    component = index % tilt.size
    u = rng.standard_normal(index.size) + mean_shift[component]
    q = rng.gamma(k, scale[component])
    log_prior = norm.logpdf(u) + gamma.logpdf(q, k, scale=2.0)
    log_mixture = np.logaddexp.reduce(norm.logpdf(u[:, None] - mean_shift[None, :])
                                      + gamma.logpdf(q[:, None], k, scale=scale[None, :]), axis=1) - math.log(tilt.size)
    means = (u / math.sqrt(n0))[:, None]
    covs = (q / (n0 - 1))[:, None, None]
    return means, covs, np.exp(log_prior - log_mixture)


def vector_fits(n0: int, index: NDArray[np.int64], lower_chol: NDArray[np.float64], rng: np.random.Generator
                ) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]:
    """:func:`scalar_fits` for d > 1: fitted means (G, d) and covariances (G, d, d) of nominals learned from
    ``n0`` independent values of N(0, R), R = L·Lᵀ (``lower_chol`` L), drawn by importance sampling, and
    their weights (G,), mean 1.

    The exact law: u = √N0·L⁻¹μ̂ ~ N(0, I) and S = (N0 − 1)·Σ̂ ~ Wishart(N0 − 1, R), independent. Proposal
    t (of :data:`TILTS`, nominal g takes ``index[g] mod len(TILTS)``) moves u by −t·c_u along
    e = Lᵀ1/‖Lᵀ1‖ (the most likely way for μ̂ to fall on every axis at once, where the boundary's
    streams sit above all of them) and scales the Wishart's scale matrix by exp(−2·t·c_s·σ_logσ̂), every
    spread narrower, σ_logσ̂ = 1/√(2·(N0 − 1)·d) the standard deviation of the log of the overall spread
    (tr(R⁻¹S)/(d·(N0 − 1)))^½ — in d = 1 the scalar case's — (c_u, c_s) :data:`TILT_DIRECTION`. S is drawn by Bartlett's
    decomposition S = c·L·A·Aᵀ·Lᵀ (A lower triangular, A_ii² ~ χ²(N0 − 1 − i), A_ij ~ N(0, 1) below);
    the Wishart densities of the proposals differ only through c: log W(S; n, c·R) = const −
    (n·d/2)·log c − tr(R⁻¹S)/(2c), with tr(R⁻¹S) = c·‖A‖². Weights by the balance heuristic."""
    d, dof = lower_chol.shape[0], n0 - 1
    sd_log_sd = 1.0 / math.sqrt(2.0 * dof * d)      # of the overall spread, (tr(R⁻¹S)/(d·dof))^½
    tilt = np.asarray(TILTS)
    direction = lower_chol.T @ np.ones(d)
    direction /= np.linalg.norm(direction)
    mean_shift = -tilt[:, None] * TILT_DIRECTION[0] * direction[None, :]            # (K, d)
    log_c = -2.0 * tilt * TILT_DIRECTION[1] * sd_log_sd                              # (K,)
    component = index % tilt.size
    u = rng.standard_normal((index.size, d)) + mean_shift[component]
    bartlett = np.zeros((index.size, d, d))
    rows, cols = np.tril_indices(d, -1)
    bartlett[:, rows, cols] = rng.standard_normal((index.size, rows.size))
    bartlett[:, np.arange(d), np.arange(d)] = np.sqrt(rng.chisquare(dof - np.arange(d), size=(index.size, d)))
    factor = np.exp(0.5 * log_c[component])[:, None, None] * (lower_chol[None] @ bartlett)
    scatter = factor @ np.swapaxes(factor, 1, 2)                                     # S (G, d, d)
    trace = np.exp(log_c[component]) * np.einsum("gij,gij->g", bartlett, bartlett)   # tr(R⁻¹S)
    log_prior = -0.5 * np.einsum("gi,gi->g", u, u) - 0.5 * trace
    diff = u[:, None, :] - mean_shift[None, :, :]
    log_proposals = (-0.5 * np.einsum("gki,gki->gk", diff, diff) - 0.5 * dof * d * log_c[None, :]
                     - 0.5 * trace[:, None] / np.exp(log_c)[None, :])
    log_mixture = np.logaddexp.reduce(log_proposals, axis=1) - math.log(tilt.size)
    means = (u @ lower_chol.T) / math.sqrt(n0)
    return means, scatter / dof, np.exp(log_prior - log_mixture)
