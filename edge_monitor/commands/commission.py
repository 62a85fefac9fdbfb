"""``edge-monitor commission``: identify the nominal friction model from nominal friction data.

Input: a CSV with a header naming ``speed`` [rad/s], ``temperature`` [°C], ``load`` (dimensionless)
and ``friction`` (dimensionless) — data of a nominal (unworn) joint at known temperature and load,
with spread in both. Output: a ``[friction]`` TOML section (the agent's config; keys are the
FrictionParams field names) and a JSON report with standard errors and the covariance.
α and the wear parameters (fsw, fvw, vsw) are kept from ``--base`` (default: the docs/ALGORITHMS.md §1 table).
Eleven parameters need data that can tell them apart: with fewer than 3 points per parameter, or with a
standard error above half its estimate for any parameter, the result is marked not identified (a
warning, ``"identified": false`` in the report, a comment in the TOML): collect more points, or keep --base.
"""

from __future__ import annotations

import argparse
import json
import sys
import tomllib
from pathlib import Path

from edge_monitor.offline.commissioning import CommissioningDataError, identify, load_csv
from joint_model.friction import DEFAULT_PARAMS, FrictionParams
from protocol.console import EXIT_FAILURE, EXIT_USAGE

#: Fewest data points per identified parameter, and the largest standard error relative to its estimate,
#: of a model the data identify (well-spread nominal data: ≤ 0.15, tests/test_commissioning.py).
POINTS_PER_PARAMETER, MAX_RELATIVE_ERROR = 3, 0.5


def add_parser(subparsers: argparse._SubParsersAction) -> argparse.ArgumentParser:
    parser = subparsers.add_parser("commission", help="identify the nominal friction model (variable projection)",
                                   description=__doc__)
    parser.add_argument("data", type=Path, help="CSV with columns speed, temperature, load, friction")
    parser.add_argument("--base", type=Path,
                        help="TOML whose [friction] table gives alpha and the wear parameters (default: §1 table)")
    parser.add_argument("-o", "--out", type=Path, help="write the [friction] TOML section here (default: stdout)")
    parser.add_argument("--report", type=Path, help="write the JSON report (estimates, std errors) here")
    parser.add_argument("--json", action="store_true", help="print the JSON report on stdout")
    parser.set_defaults(func=run)
    return parser


def _base_params(path: Path | None) -> FrictionParams:
    if path is None:
        return DEFAULT_PARAMS
    try:
        with open(path, "rb") as handle:
            table = tomllib.load(handle).get("friction", {})
    except (OSError, tomllib.TOMLDecodeError) as exc:
        raise CommissioningDataError(f"--base {path}: cannot read TOML: {exc}") from None
    if not isinstance(table, dict):
        raise CommissioningDataError(f"--base {path}: [friction] must be a table")
    return FrictionParams.from_mapping(table, where=f"{path}: friction")


def unidentified(report: dict) -> str | None:
    """Why the data do not identify the model (too few points, parameters the data cannot tell), or None."""
    n, params, errors = report["n_points"], report["parameters"], report["std_errors"]
    loose = [name for name, value in params.items()
             if not errors[name] <= MAX_RELATIVE_ERROR * abs(value)]       # NaN errors count as loose
    if n >= POINTS_PER_PARAMETER * len(params) and not loose:
        return None
    return (f"{n} points for {len(params)} parameters"
            + (f"; not identified (standard error above {MAX_RELATIVE_ERROR:.0%} of the estimate): {', '.join(loose)}"
               if loose else "")
            + f": collect ≥ {POINTS_PER_PARAMETER * len(params)} points spread over speed, temperature and load, "
              "or keep the shipped table (--base)")


def run(args: argparse.Namespace) -> int:
    try:
        base = _base_params(args.base)
        result = identify(load_csv(args.data), base)
    except ValueError as exc:  # CommissioningDataError and FrictionParams validation errors
        print(f"edge-monitor commission: {exc}", file=sys.stderr)
        return EXIT_USAGE
    toml_text = result.to_toml()
    problem = unidentified(result.report())
    if problem:
        print(f"edge-monitor commission: WARNING: {problem}", file=sys.stderr)
        toml_text = f"# WARNING (edge-monitor commission): {problem}\n" + toml_text
    report = json.dumps({**result.report(), "identified": not problem, "warning": problem}, indent=2)
    try:
        if args.out is not None:
            args.out.write_text(toml_text, encoding="utf-8")
        if args.report is not None:
            args.report.write_text(report + "\n", encoding="utf-8")
    except OSError as exc:
        print(f"edge-monitor commission: cannot write output: {exc}", file=sys.stderr)
        return EXIT_FAILURE
    if args.json:
        print(report)
    elif args.out is None:
        print(toml_text, end="")
    return 0
