"""``edge-monitor glr``: offline GLR test of a recorded quantity for a bias change.

Reads a nominal CSV and a test CSV (header row; the columns named by --columns, by default every
numeric column, are the dimensions of one observation; text-only columns such as timestamps are
ignored), fits the nominal density and tests the test rows for a shift of it. Exit code 0 when the
test ran (alarm or not), 2 on bad input (bad option values also print the usage).

Memory and time stay bounded whatever the files and options ask for: a CSV must be a regular file of
at most :data:`MAX_CSV_BYTES`; the density fit and every rows × components matrix hold at most
:data:`MAX_CELLS` numbers; the unknown-change search and the bootstrap do at most :data:`MAX_WORK`
component evaluations. A request past a limit is a usage error naming the option that brings it
within (``--window``, fewer rows or draws, ``--density gauss``).
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
from protocol.files import NotARegularFile, require_regular

#: Largest CSV read [bytes].
MAX_CSV_BYTES = 256 << 20
#: Largest matrix of rows × mixture components (or nominal rows² for the GCE fit) [numbers]: 256 MiB.
MAX_CELLS = 1 << 25
#: Largest number of component evaluations of the unknown-change search or the bootstrap (≈ 1 µs each).
MAX_WORK = 10 ** 8
MAX_DRAWS = 1_000_000


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
        require_regular(path)
        if path.stat().st_size > MAX_CSV_BYTES:
            raise CsvInputError(f"{path}: larger than {MAX_CSV_BYTES} bytes; test a shorter span of data")
        with open(path, newline="", encoding="utf-8") as fh:
            rows = list(csv.reader(fh))
    except NotARegularFile as exc:
        raise CsvInputError(f"{path}: {exc.reason}; give a CSV file") from None
    except OSError as exc:
        raise CsvInputError(f"{path}: cannot read ({exc.strerror})") from exc
    except (UnicodeDecodeError, csv.Error) as exc:
        raise CsvInputError(f"{path}: not a UTF-8 CSV file ({exc})") from None
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
    if not 1 <= args.bootstrap_draws <= MAX_DRAWS:
        raise UsageError(f"--bootstrap-draws {args.bootstrap_draws}: give 1 … {MAX_DRAWS} draws")
    if args.seed < 0:
        raise UsageError(f"--seed {args.seed}: give an integer ≥ 0")
    return pf


def check_size(args: argparse.Namespace, n_nominal: int, n_test: int, dim: int, components: int | None) -> None:
    """UsageError when the test would pass :data:`MAX_CELLS` or :data:`MAX_WORK` (``components``:
    None before the fit, then a KDE has one per nominal row and a GCE at most that many)."""
    k = components if components is not None else (1 if args.density == "gauss" else n_nominal)
    if args.density == "gce" and components is None and n_nominal * n_nominal * dim > MAX_CELLS:
        raise UsageError(f"--density gce on {n_nominal} nominal rows needs {n_nominal}² × {dim} numbers "
                         f"(limit {MAX_CELLS}); give fewer nominal rows or --density gauss")
    if (n_test + n_nominal) * k > MAX_CELLS:
        raise UsageError(f"--density {args.density}: {n_nominal + n_test} rows × {k} components is more than "
                         f"{MAX_CELLS} numbers; give fewer rows or --density gauss")
    if args.change_time == "unknown":
        starts = min(args.window or n_test, n_test)
        if starts * n_test * k > MAX_WORK:
            raise UsageError(f"--change-time unknown over {n_test} rows ({starts} change times × {n_test} rows × "
                             f"{k} components) is more than {MAX_WORK:g} evaluations; give --window W with "
                             f"W × {n_test} × {k} ≤ {MAX_WORK:g} or fewer rows"
                             + ("" if k == 1 else ", or --density gauss"))
    if args.threshold == "bootstrap":
        cells = args.bootstrap_draws * (n_test + n_nominal)       # one Gaussian: all draws at once
        work, limit = (cells, MAX_CELLS) if k == 1 else (cells * k, MAX_WORK)
        if work > limit:
            raise UsageError(f"--bootstrap-draws {args.bootstrap_draws} × {n_test + n_nominal} rows × {k} "
                             f"component(s) is more than {limit:g}; give fewer draws")


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
        check_size(args, len(nominal), len(test), nominal.shape[1], None)
        density = fit_density(nominal, args.density)
        check_size(args, len(nominal), len(test), nominal.shape[1], density.n_components)
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
