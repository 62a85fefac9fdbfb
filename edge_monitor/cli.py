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

#: (subcommand, module under edge_monitor.commands, issue that owns it)
SUBCOMMANDS: tuple[tuple[str, str, int], ...] = (
    ("run", "run", 7),
    ("replay", "replay", 4),
    ("demo", "demo", 7),
    ("design", "design", 4),
    ("commission", "commission", 4),
    ("fit-weights", "fit_weights", 5),
    ("glr", "glr", 6),
    ("view", "view", 7),
)


def _add_placeholder(subparsers: argparse._SubParsersAction, name: str, issue: int) -> None:
    parser = subparsers.add_parser(name, help=f"(not available yet: issue #{issue})")

    def _not_yet(_args: argparse.Namespace) -> int:
        print(f"edge-monitor {name}: not implemented yet (owned by issue #{issue})", file=sys.stderr)
        return 2

    parser.set_defaults(func=_not_yet)


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="edge-monitor", description=__doc__)
    parser.add_argument("-v", "--verbose", action="count", default=0, help="more log output (-vv: debug)")
    subparsers = parser.add_subparsers(dest="command", required=True)
    for name, module_name, issue in SUBCOMMANDS:
        try:
            module = importlib.import_module(f"edge_monitor.commands.{module_name}")
        except ModuleNotFoundError as exc:
            if exc.name != f"edge_monitor.commands.{module_name}":
                raise
            _add_placeholder(subparsers, name, issue)
            continue
        module.add_parser(subparsers)
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
