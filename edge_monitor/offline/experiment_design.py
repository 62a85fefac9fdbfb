"""Experiment design: friction speeds that minimise the Cramér–Rao bound of wear (docs/ALGORITHMS.md §3).

N ≥ 2: minimise ``[F(v)⁻¹]₂₂`` at a design point (ξ', ϖ', μl, σl, σ) over speeds
``vmin ≤ vi ≤ vmax`` with a minimum separation ``v(i+1) − v(i) ≥ δ`` (speeds kept sorted, so the
separation constraints are linear). The criterion is evaluated for many candidate designs at once
(Σ⁻¹ by Sherman–Morrison, since ``Σ = σ²I + σl²·s·sᵀ``); the best candidates of a grid (N = 2) or of
seeded random feasible starts (N ≥ 3) are refined with SLSQP. N ≥ 2 is well posed only with
distinct speeds (F is singular otherwise).

N = 1: ξ and ϖ cannot be separated by one datum; the criterion is the inverse Fisher information of
the temperature-marginalised likelihood (Monte Carlo, Nξ = 100 temperature samples, Nf = 200 draws,
fixed seed), minimised over a 1-D grid of speeds, then refined locally on a finer grid.
Speeds in rad/s, wear and its bound in wear units (bound = a variance).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray
from scipy.optimize import minimize

from edge_monitor.features.wear_information import crlb_wear, marginal_fisher_wear
from joint_model.friction import (
    DEFAULT_PARAMS,
    FRICTION_NOISE_STD,
    WEAR_MAX,
    FrictionParams,
    jacobian_temperature_wear,
    load_sensitivity,
)

#: Highest motor speed a design may use [rad/s] (motors turn at most a few hundred rad/s).
MAX_SPEED = 10_000.0


class DesignError(ValueError):
    """Design problem with invalid or infeasible settings (message names the option)."""


@dataclass(frozen=True)
class DesignPoint:
    """Where the bound is evaluated: temperature [°C], wear, load mean/std, datum noise std."""

    temperature: float = 40.0
    wear: float = 35.0
    load_mean: float = 0.5
    load_std: float = 0.1
    noise_std: float = FRICTION_NOISE_STD

    def to_dict(self) -> dict[str, float]:
        return {"temperature": self.temperature, "wear": self.wear, "load_mean": self.load_mean,
                "load_std": self.load_std, "noise_std": self.noise_std}


@dataclass(frozen=True)
class DesignResult:
    """Optimal speeds (sorted, rad/s) and the bound of ϖ there (variance ``wear_crlb``)."""

    speeds: list[float]
    wear_crlb: float
    design_point: DesignPoint
    speed_min: float
    speed_max: float
    min_separation: float
    method: str
    n_starts: int = 0

    @property
    def wear_std(self) -> float:
        return math.sqrt(self.wear_crlb) if math.isfinite(self.wear_crlb) else math.inf

    def to_json(self) -> dict:
        """JSON of ``edge-monitor design --json`` (docs/OUTPUTS.md); ``--speeds-from`` reads ``speeds``."""
        def num(x: float) -> float | None:
            return float(x) if math.isfinite(x) else None
        return {"speeds": [round(float(v), 6) for v in self.speeds], "wear_crlb": num(self.wear_crlb),
                "wear_std": num(self.wear_std), "design_point": self.design_point.to_dict(),
                "speed_min": self.speed_min, "speed_max": self.speed_max,
                "min_separation": self.min_separation, "method": self.method}


def batch_crlb_wear(speed_sets: NDArray[np.float64], point: DesignPoint,
                    params: FrictionParams = DEFAULT_PARAMS) -> NDArray[np.float64]:
    """``[F⁻¹]₂₂`` for each row of ``speed_sets`` (M × N) at once; inf where F is singular.

    ``Σ⁻¹ = (I − c·s·sᵀ)/σ²`` with ``c = σl²/(σ² + σl²·‖s‖²)``, so
    ``F = (JᵀJ − c·(Jᵀs)(Jᵀs)ᵀ)/σ²``.
    """
    v = np.asarray(speed_sets, dtype=float)
    m, n = v.shape
    jac = jacobian_temperature_wear(v.reshape(-1), point.temperature, point.wear, params).reshape(m, n, 2)
    s = load_sensitivity(v, params)
    sigma2, load2 = point.noise_std ** 2, point.load_std ** 2
    c = load2 / (sigma2 + load2 * np.sum(s * s, axis=1))
    jtj = np.einsum("mni,mnj->mij", jac, jac)
    jts = np.einsum("mni,mn->mi", jac, s)
    fisher = (jtj - c[:, None, None] * jts[:, :, None] * jts[:, None, :]) / sigma2
    det = fisher[:, 0, 0] * fisher[:, 1, 1] - fisher[:, 0, 1] ** 2
    ok = det > 1e-12 * fisher[:, 0, 0] * fisher[:, 1, 1]
    with np.errstate(divide="ignore", invalid="ignore"):
        return np.where(ok, fisher[:, 0, 0] / np.where(ok, det, 1.0), np.inf)


def design_speeds(n_points: int, temperature: float = 40.0, wear: float = 35.0, load_mean: float = 0.5,
                  load_std: float = 0.1, noise_std: float = FRICTION_NOISE_STD, speed_min: float = 1.0,
                  speed_max: float = 280.0, min_separation: float = 5.0,
                  params: FrictionParams = DEFAULT_PARAMS, seed: int = 0) -> DesignResult:
    """Speeds [rad/s] minimising the Cramér–Rao bound of ϖ at the design point (deterministic)."""
    point = DesignPoint(float(temperature), float(wear), float(load_mean), float(load_std), float(noise_std))
    _validate(n_points, point, speed_min, speed_max, min_separation)
    if n_points == 1:
        speed, bound = _design_single(point, speed_min, speed_max, params)
        speeds, method, n_starts = [speed], "marginal-fisher-grid", 0
    else:
        speeds, bound, n_starts = _design_multi(n_points, point, speed_min, speed_max, min_separation, params, seed)
        method = "grid+slsqp"
    return DesignResult(speeds=speeds, wear_crlb=bound, design_point=point, speed_min=float(speed_min),
                        speed_max=float(speed_max), min_separation=float(min_separation), method=method,
                        n_starts=n_starts)


def _validate(n_points: int, point: DesignPoint, speed_min: float, speed_max: float,
              min_separation: float) -> None:
    if int(n_points) != n_points or n_points < 1:
        raise DesignError(f"--points: need an integer ≥ 1, got {n_points!r}")
    values = {"--temperature": point.temperature, "--wear": point.wear, "--load-mean": point.load_mean,
              "--load-std": point.load_std, "--noise-std": point.noise_std, "--speed-min": speed_min,
              "--speed-max": speed_max, "--min-separation": min_separation}
    for name, value in values.items():
        if not math.isfinite(value):
            raise DesignError(f"{name}: must be finite, got {value!r}")
    ranges = {"--temperature": (point.temperature, -40.0, 150.0), "--wear": (point.wear, 0.0, WEAR_MAX),
              "--load-mean": (point.load_mean, 0.0, 10.0), "--load-std": (point.load_std, 0.0, 10.0),
              "--noise-std": (point.noise_std, 1e-6, 1.0), "--min-separation": (min_separation, 0.0, MAX_SPEED)}
    for name, (value, low, high) in ranges.items():      # physical ranges: beyond them the model is meaningless
        if not low <= value <= high:
            raise DesignError(f"{name}: must be {low:g} … {high:g}, got {value!r}")
    if not 0 < speed_min < speed_max <= MAX_SPEED:
        raise DesignError(f"--speed-min/--speed-max: need 0 < min < max ≤ {MAX_SPEED:g} rad/s, "
                          f"got {speed_min}, {speed_max}")
    if (n_points - 1) * min_separation > speed_max - speed_min:
        raise DesignError(f"--min-separation: {n_points} speeds {min_separation} rad/s apart do not fit in "
                          f"[{speed_min}, {speed_max}]; lower --points or --min-separation")


def _design_single(point: DesignPoint, speed_min: float, speed_max: float,
                   params: FrictionParams) -> tuple[float, float]:
    """1-D grid (coarse, then fine around the best) of the inverse marginal Fisher information."""
    def bound(speed: float) -> float:
        info = marginal_fisher_wear(speed, point.wear, point.load_mean, point.load_std, point.noise_std, params)
        return math.inf if info <= 0 else 1.0 / info

    coarse = np.linspace(speed_min, speed_max, 140)
    values = np.array([bound(v) for v in coarse])
    k = int(np.argmin(values))
    fine = np.linspace(coarse[max(k - 1, 0)], coarse[min(k + 1, coarse.size - 1)], 41)
    fine_values = np.array([bound(v) for v in fine])
    j = int(np.argmin(fine_values))
    return float(fine[j]), float(fine_values[j])


def _feasible_starts(n_points: int, speed_min: float, speed_max: float, min_separation: float,
                     n_random: int, rng: np.random.Generator) -> NDArray[np.float64]:
    """Sorted feasible designs: a grid for N = 2, seeded random ones otherwise (M × N)."""
    if n_points == 2:
        g = np.linspace(speed_min, speed_max, 112)
        a, b = np.meshgrid(g, g, indexing="ij")
        pairs = np.column_stack([a.ravel(), b.ravel()])
        return pairs[pairs[:, 1] - pairs[:, 0] >= min_separation]
    # Random gaps: sort uniforms on the slack interval, then add the separations back.
    slack = speed_max - speed_min - (n_points - 1) * min_separation
    u = np.sort(rng.uniform(0.0, slack, size=(n_random, n_points)), axis=1)
    return speed_min + u + min_separation * np.arange(n_points)[None, :]


def _design_multi(n_points: int, point: DesignPoint, speed_min: float, speed_max: float,
                  min_separation: float, params: FrictionParams, seed: int) -> tuple[list[float], float, int]:
    rng = np.random.default_rng(seed)
    starts = _feasible_starts(n_points, speed_min, speed_max, min_separation, 4000, rng)
    values = batch_crlb_wear(starts, point, params)
    order = np.argsort(values)[:8]
    n = n_points
    diff = np.zeros((n - 1, n))
    diff[np.arange(n - 1), np.arange(n - 1)] = -1.0
    diff[np.arange(n - 1), np.arange(1, n)] = 1.0
    constraints = [{"type": "ineq", "fun": lambda x: diff @ x - min_separation, "jac": lambda x: diff}]
    scale = float(values[order[0]])

    def objective(x: NDArray[np.float64]) -> float:
        value = float(batch_crlb_wear(x[None, :], point, params)[0])
        return value / scale if math.isfinite(value) else 1e12

    best_x, best_value = starts[order[0]], float(values[order[0]])
    for k in order:
        fit = minimize(objective, starts[k], method="SLSQP", bounds=[(speed_min, speed_max)] * n,
                       constraints=constraints, options={"ftol": 1e-12, "maxiter": 200})
        x = np.clip(np.sort(fit.x), speed_min, speed_max)
        if np.all(np.diff(x) >= min_separation - 1e-6):
            value = crlb_wear(x, point.temperature, point.wear, point.load_mean, point.load_std, params,
                              point.noise_std)
            if value < best_value:
                best_x, best_value = x, value
    return [float(v) for v in best_x], float(best_value), int(starts.shape[0])
