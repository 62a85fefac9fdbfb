"""Experiment designs in coded levels (rows = runs, columns = factors, levels −2 … 2).

* :func:`fractional_factorial`: the 2^(n−1) half fraction at ±1 with generator x_n = x_1·…·x_{n−1}
  (defining relation I = x_1·…·x_n, resolution n: for n ≥ 5 no main effect or two-factor interaction
  is aliased with another).
* :func:`central_composite`: that fraction, one centre point and star points at ±2 on every axis:
  2^(n−1) + 2n + 1 runs (45 for n = 6, 27 for n = 5, 11 for n = 3; for n = 4 the full factorial, 25).
* :func:`validation_design`: runs on *other* levels (±0.5, ±1.5), a seeded Latin hypercube: every
  factor visits the four levels equally often, so the surrogate is checked away from the points it
  was fitted on.
* :func:`quadratic_terms` / :func:`check_estimable`: the second-order model's terms and the refusal of
  a design too small (or too degenerate) for it.
* :func:`load_design_csv`: a user's own design (``--design FILE.csv``).
"""

from __future__ import annotations

import csv
import io
import itertools
from pathlib import Path
from typing import Sequence

import numpy as np
from numpy.typing import NDArray

#: Coded level of the star points.
STAR = 2.0
#: Levels of the validation design.
VALIDATION_LEVELS = (-1.5, -0.5, 0.5, 1.5)


class DesignError(ValueError):
    """A design that cannot serve the surrogate model; the message says why and what to change."""


def fractional_factorial(n: int) -> NDArray[np.float64]:
    """2^(n−1) × n half fraction at ±1 (n ≥ 2), last column the product of the others."""
    if n < 2:
        raise DesignError(f"a fractional factorial needs at least 2 factors, got {n}")
    base = np.array(list(itertools.product((-1.0, 1.0), repeat=n - 1)))
    return np.column_stack([base, np.prod(base, axis=1)])


def resolution(design: NDArray[np.float64], max_order: int | None = None) -> int | None:
    """Length of the shortest word of the defining relation of a two-level design (a product of k
    columns that is constant), or None when no product up to ``max_order`` columns is constant."""
    x = np.asarray(design, dtype=float)
    n = x.shape[1]
    for k in range(1, (max_order or n) + 1):
        for cols in itertools.combinations(range(n), k):
            product = np.prod(x[:, cols], axis=1)
            if np.all(product == product[0]):
                return k
    return None


def central_composite(n: int, star: float = STAR) -> NDArray[np.float64]:
    """Central composite design: half fraction at ±1, one centre point, star points at ±``star``.

    For n = 4 the half fraction has resolution IV (two-factor interactions aliased in pairs, which the
    star points cannot separate), so the full 2^4 factorial is used there (25 runs)."""
    stars = np.zeros((2 * n, n))
    for i in range(n):
        stars[2 * i, i], stars[2 * i + 1, i] = -star, star
    design = np.vstack([fractional_factorial(n), np.zeros((1, n)), stars])
    if np.linalg.matrix_rank(quadratic_matrix(design)) < len(quadratic_terms([str(i) for i in range(n)])):
        full = np.array(list(itertools.product((-1.0, 1.0), repeat=n)))
        design = np.vstack([full, np.zeros((1, n)), stars])
    return design


def validation_design(n: int, runs: int, seed: int = 0) -> NDArray[np.float64]:
    """``runs`` × n Latin hypercube on :data:`VALIDATION_LEVELS` (each factor cycles through the levels
    in its own seeded random order)."""
    if runs < 0:
        raise DesignError(f"validation runs must be ≥ 0, got {runs}")
    rng = np.random.default_rng(seed)
    levels = np.asarray(VALIDATION_LEVELS)
    cols = [rng.permutation(np.resize(levels, runs)) for _ in range(n)]
    return np.column_stack(cols) if runs else np.zeros((0, n))


def quadratic_terms(names: Sequence[str]) -> list[str]:
    """Names of the second-order model's terms: ``1``, main effects, pairwise products ``a*b``, squares ``a^2``."""
    out = ["1", *names]
    out += [f"{a}*{b}" for a, b in itertools.combinations(names, 2)]
    out += [f"{a}^2" for a in names]
    return out


def quadratic_matrix(design: NDArray[np.float64]) -> NDArray[np.float64]:
    """Regressor matrix Φ of the second-order model (columns in :func:`quadratic_terms` order)."""
    x = np.atleast_2d(np.asarray(design, dtype=float))
    n = x.shape[1]
    pairs = list(itertools.combinations(range(n), 2))
    inter = np.column_stack([x[:, i] * x[:, j] for i, j in pairs]) if pairs else np.zeros((x.shape[0], 0))
    return np.column_stack([np.ones(x.shape[0]), x, inter, x ** 2])


def check_estimable(design: NDArray[np.float64]) -> None:
    """Refuse a design with fewer runs than the second-order model has coefficients, or whose regressor
    matrix is rank deficient (some coefficients cannot be told apart)."""
    x = np.atleast_2d(np.asarray(design, dtype=float))
    n = x.shape[1]
    p = 1 + 2 * n + n * (n - 1) // 2
    if x.shape[0] < p:
        raise DesignError(f"the design has {x.shape[0]} runs but the second-order surrogate of {n} factors has "
                          f"{p} coefficients: use fewer factors or a larger design")
    rank = int(np.linalg.matrix_rank(quadratic_matrix(x)))
    if rank < p:
        raise DesignError(f"the design cannot separate the {p} coefficients of the second-order surrogate "
                          f"(rank {rank}): use a central composite design")


def load_design_csv(path: str | Path, names: Sequence[str]) -> NDArray[np.float64]:
    """A design in coded levels from a CSV file whose header names the factors (columns reordered to
    ``names``); every level within −2 … 2. :class:`DesignError` names the problem."""
    try:
        text = Path(path).read_text(encoding="utf-8")
    except (OSError, UnicodeDecodeError) as exc:
        raise DesignError(f"--design: cannot read {path}: {getattr(exc, 'strerror', None) or exc}") from None
    reader = csv.reader(io.StringIO(text))
    rows = [(reader.line_num, r) for r in reader if r and any(c.strip() for c in r)]
    if not rows:
        raise DesignError(f"--design: {path} is empty; need a header naming the factors and one row per run")
    header = [h.strip() for h in rows[0][1]]
    if sorted(header) != sorted(names):
        raise DesignError(f"--design: {path}: header {header} must name exactly the factors {list(names)}")
    for line, r in rows[1:]:
        if len(r) != len(header):
            raise DesignError(f"--design: {path}: line {line} has {len(r)} cells; every run needs exactly "
                              f"{len(header)} (one per header column)")
    try:
        values = np.array([[float(c) for c in r] for _, r in rows[1:]], dtype=float).reshape(-1, len(header))
    except ValueError:
        raise DesignError(f"--design: {path}: every run needs {len(header)} numeric coded levels") from None
    if not np.all(np.isfinite(values)) or np.any(np.abs(values) > STAR):
        raise DesignError(f"--design: {path}: coded levels must lie within −{STAR:g} … {STAR:g}")
    return values[:, [header.index(n) for n in names]]
