"""``edge-monitor glr``: offline GLR test of a recorded quantity for a bias change.

Reads a nominal CSV and a test CSV (header row; the columns named by --columns, by default every
numeric column, are the dimensions of one observation; text-only columns such as timestamps are
ignored), fits the nominal density and tests the test rows for a shift of it. Exit code 0 when the
test ran (alarm or not), 2 on bad input (bad option values also print the usage).
"""

from __future__ import annotations

import argparse
import csv
import json
import math
import sys
from pathlib import Path

import numpy as np

from edge_monitor.stats.densities import DENSITY_KINDS, fit_density
from edge_monitor.stats.glr import GLRResult, bootstrap_threshold, check_pf, glr_known_change, glr_unknown_change
from protocol.console import EXIT_USAGE, UsageError


class CsvInputError(ValueError):
    """A CSV file that cannot be read as numeric observations (names file, row and column)."""


def _is_number(cell: str) -> bool:
    try:
        float(cell)
    except ValueError:
        return False
    return True


def read_observations(path: Path, columns: list[str] | None = None) -> tuple[list[str], np.ndarray]:
    """Numeric columns of a CSV with a header row -> (column names, (n, d) array).

    ``columns``: the columns to take, by header name (each must exist); None: every column with a
    number in it (a column whose cells are all non-numeric is ignored). A non-numeric, empty or
    non-finite cell of a taken column is an error naming the row (1-based line number) and column.
    """
    try:
        with open(path, newline="", encoding="utf-8") as fh:
            rows = list(csv.reader(fh))
    except OSError as exc:
        raise CsvInputError(f"{path}: cannot read ({exc.strerror})") from exc
    if not rows:
        raise CsvInputError(f"{path}: empty file; expected a header row and data rows")
    header, body = [h.strip() for h in rows[0]], [r for r in rows[1:] if any(c.strip() for c in r)]
    if not body:
        raise CsvInputError(f"{path}: no data rows below the header")
    for i, row in enumerate(rows[1:], start=2):
        if any(c.strip() for c in row) and len(row) != len(header):
            raise CsvInputError(f"{path}: row {i} has {len(row)} cells but the header has {len(header)}")
    if columns is not None:
        missing = [c for c in columns if c not in header]
        if missing:
            raise CsvInputError(f"{path}: no column {', '.join(map(repr, missing))} (header: {header}); "
                                "fix --columns")
        numeric = [header.index(c) for c in columns]
    else:
        numeric = [j for j in range(len(header)) if any(_is_number(r[j].strip()) for r in body)]
    if not numeric:
        raise CsvInputError(f"{path}: no numeric column found (header: {header})")
    data = np.empty((len(body), len(numeric)))
    line_numbers = [i for i, r in enumerate(rows[1:], start=2) if any(c.strip() for c in r)]
    for k, (line, row) in enumerate(zip(line_numbers, body)):
        for m, j in enumerate(numeric):
            cell = row[j].strip()
            value = float(cell) if _is_number(cell) else math.nan
            if not math.isfinite(value):
                raise CsvInputError(f"{path}: row {line}, column {header[j]!r}: {cell!r} is not a finite "
                                    "number; fix or remove that row")
            data[k, m] = value
    return [header[j] for j in numeric], data


def add_parser(subparsers: argparse._SubParsersAction) -> argparse.ArgumentParser:
    parser = subparsers.add_parser(
        "glr", help="offline GLR test of a recorded quantity for a bias change",
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--nominal", required=True, type=Path, help="CSV of nominal (healthy) observations")
    parser.add_argument("--test", required=True, type=Path, help="CSV of observations to test")
    parser.add_argument("--columns", metavar="NAME,...",
                        help="the columns that make up one observation, by header name (default: every column "
                             "with numbers, e.g. a cycle number too; one column: a 1-D test)")
    parser.add_argument("--density", choices=DENSITY_KINDS, default="gce",
                        help="nominal density model")
    parser.add_argument("--pf", type=float, default=0.01, help="false-alarm probability of the test, in (0, 1)")
    parser.add_argument("--change-time", choices=("known", "unknown"), default="known",
                        help="known: the change starts at the first test row; unknown: max over start rows")
    parser.add_argument("--window", type=int, default=None,
                        help="unknown change time: consider only the last W rows as change times")
    parser.add_argument("--threshold", choices=("asymptotic", "bootstrap"), default="asymptotic",
                        help="asymptotic: ½·χ²_d quantile; bootstrap: calibrated on the nominal data "
                             "(known change time only)")
    parser.add_argument("--bootstrap-draws", type=int, default=2000, help="draws for --threshold bootstrap")
    parser.add_argument("--seed", type=int, default=0, help="seed of the bootstrap")
    parser.add_argument("--json", action="store_true", help="print one JSON object")
    parser.set_defaults(func=run)
    return parser


def _fail(message: str) -> int:
    print(f"edge-monitor glr: error: {message}", file=sys.stderr)
    return EXIT_USAGE


def _check_options(args: argparse.Namespace) -> float:
    """The false-alarm probability; bad option values raise UsageError."""
    try:
        pf = check_pf(args.pf)
    except ValueError as exc:
        raise UsageError(str(exc)) from None
    if args.window is not None and args.window < 1:
        raise UsageError(f"--window {args.window} must be ≥ 1 row")
    if args.threshold == "bootstrap" and args.change_time != "known":
        raise UsageError("--threshold bootstrap is available for --change-time known only")
    return pf


def run(args: argparse.Namespace) -> int:
    pf = _check_options(args)
    columns = None if args.columns is None else [c.strip() for c in args.columns.split(",")]
    if columns is not None and (not all(columns) or len(set(columns)) != len(columns)):
        raise UsageError(f"--columns {args.columns!r}: give distinct header names separated by commas")
    try:
        nominal_cols, nominal = read_observations(args.nominal, columns)
        test_cols, test = read_observations(args.test, columns)
        if nominal.shape[1] != test.shape[1]:
            raise ValueError(f"dimension mismatch: nominal has {nominal.shape[1]} numeric column(s) "
                             f"{nominal_cols}, test has {test.shape[1]} {test_cols}; use the same columns")
        flat = [name for name, col in zip(nominal_cols, nominal.T) if np.ptp(col) == 0.0]
        if flat:
            raise ValueError(f"{args.nominal}: nominal column(s) {flat} are constant; a density cannot be "
                             "fitted to constant data (drop the column or record more varied nominal data)")
        density = fit_density(nominal, args.density)
        threshold = None
        if args.threshold == "bootstrap":
            threshold = bootstrap_threshold(nominal, density, len(test), pf, args.bootstrap_draws, args.seed)
        if args.change_time == "known":
            result = glr_known_change(test, density, pf, threshold=threshold)
        else:
            result = glr_unknown_change(test, density, pf, window=args.window)
    except ValueError as exc:
        return _fail(str(exc))
    _print(result, args, density.n_components, test_cols, len(nominal))
    return 0


def _print(result: GLRResult, args: argparse.Namespace, components: int, columns: list[str], n0: int) -> None:
    out: dict[str, object] = {"statistic": result.statistic, "threshold": result.threshold,
                              "alarm": result.alarm, "delta": result.delta,
                              "miss_probability": result.miss_probability, "components": components}
    if args.change_time == "unknown":
        out["change_index"] = result.change_index
    out.update({"density": args.density, "pf": args.pf, "change_time": args.change_time,
                "threshold_method": args.threshold, "columns": columns, "n_nominal": n0, "n_test": result.n})
    if args.json:
        print(json.dumps(out))
        return
    verdict = "ALARM: bias change detected" if result.alarm else "no change detected"
    print(f"{verdict} (statistic {result.statistic:.4g} vs threshold {result.threshold:.4g}, Pf {args.pf:g})")
    print(f"estimated change Δ̂ = {result.delta} in columns {columns}; miss probability {result.miss_probability:.3g}")
    if args.change_time == "unknown":
        print(f"estimated change starts at test row index {result.change_index} (0-based)")
    print(f"nominal {args.density} density with {components} component(s) from {n0} rows")
