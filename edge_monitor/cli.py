"""``edge-monitor`` command line: dispatches to one module per subcommand (``edge_monitor.commands``)."""

from __future__ import annotations

import os

# Before numpy loads: on a small edge box a threaded BLAS makes small products (~10⁴ elements) take
# milliseconds instead of microseconds when the other cores are busy (measured: 30 ms vs 10 µs).
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import argparse
import importlib
import logging
import sys
from typing import Sequence

from protocol import package_version

#: Subcommands and the module under ``edge_monitor.commands`` that defines each.
SUBCOMMANDS: tuple[tuple[str, str], ...] = (
    ("run", "run"), ("replay", "replay"), ("demo", "demo"), ("design", "design"),
    ("commission", "commission"), ("fit-weights", "fit_weights"), ("glr", "glr"), ("view", "view"),
)


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="edge-monitor", description=__doc__)
    parser.add_argument("--version", action="version", version=f"%(prog)s {package_version()}")
    parser.add_argument("-v", "--verbose", action="count", default=0, help="more log output (-vv: debug)")
    subparsers = parser.add_subparsers(dest="command", required=True)
    for _name, module_name in SUBCOMMANDS:
        importlib.import_module(f"edge_monitor.commands.{module_name}").add_parser(subparsers)
    return parser


def configure_logging(verbosity: int) -> None:
    level = logging.WARNING if verbosity <= 0 else logging.INFO if verbosity == 1 else logging.DEBUG
    logging.basicConfig(level=level, format="%(asctime)s %(levelname)s %(name)s: %(message)s")


def main(argv: Sequence[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    configure_logging(args.verbose)
    return int(args.func(args) or 0)


if __name__ == "__main__":
    sys.exit(main())
