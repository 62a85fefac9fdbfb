"""edge-monitor: the edge condition monitor for robot joints (the agent, its tools and its outputs).

run monitors a live CAN link, replay a recorded log; demo shows the whole system on a simulated
robot. -v/-vv/-q work before and after the subcommand. "edge-monitor COMMAND --help" tells more.
"""

from __future__ import annotations

import os

# Before numpy loads: on a small edge box a threaded BLAS makes small products (~10⁴ elements) take
# milliseconds instead of microseconds when the other cores are busy (measured: 30 ms vs 10 µs).
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import argparse
import importlib
import sys
from typing import Sequence

from protocol import package_version
from protocol.console import (
    UsageError,
    configure_logging,
    guarded_stdout,
    install_conventions,
    interrupted_exit,
    stdout_failure_exit,
    subcommands,
    terminate_like_interrupt,
    usage_error,
    verbosity,
)

#: Subcommands and the module under ``edge_monitor.commands`` that defines each.
SUBCOMMANDS: tuple[tuple[str, str], ...] = (
    ("run", "run"), ("replay", "replay"), ("demo", "demo"), ("design", "design"),
    ("commission", "commission"), ("fit-weights", "fit_weights"), ("glr", "glr"), ("view", "view"),
    ("evaluate", "evaluate"), ("check-mapping", "check_mapping"), ("export-trace", "export_trace"),
    ("acknowledge", "acknowledge"), ("listen", "listen"), ("schema", "schema"), ("router", "router"),
    ("slcan-hub", "slcan_hub"), ("historian", "historian"), ("history", "history"), ("deploy", "deploy"),
)


def build_parser(only: str | None = None) -> argparse.ArgumentParser:
    """The parser of every subcommand, or of ``only`` that one (a command starts without importing the
    others: ``router`` and ``listen`` need no numerics)."""
    parser = argparse.ArgumentParser(prog="edge-monitor", description=__doc__)
    parser.add_argument("--version", action="version", version=f"%(prog)s {package_version()}")
    subparsers = parser.add_subparsers(dest="command", required=True)
    for name, module_name in SUBCOMMANDS:
        if only is None or name == only:
            importlib.import_module(f"edge_monitor.commands.{module_name}").add_parser(subparsers)
    install_conventions(parser)
    return parser


def requested_subcommand(argv: Sequence[str]) -> str | None:
    """The subcommand ``argv`` names (the first word that is not an option), if it is one."""
    word = next((token for token in argv if not token.startswith("-")), None)
    return word if word in dict(SUBCOMMANDS) else None


def main(argv: Sequence[str] | None = None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    parser = build_parser(requested_subcommand(argv))
    args = parser.parse_args(argv)
    configure_logging(verbosity(args))
    try:
        with terminate_like_interrupt(), guarded_stdout():
            return int(args.func(args) or 0)
    except UsageError as exc:       # a bad value found after parsing: the subcommand's usage, exit 2
        return usage_error(subcommands(parser)[args.command], str(exc))
    except KeyboardInterrupt as exc:
        return interrupted_exit(f"edge-monitor {args.command}", exc)
    except OSError as exc:          # standard output could not be written (> /dev/full, a full disk): one line
        code = stdout_failure_exit(f"edge-monitor {args.command}", exc)
        if code is None:
            raise
        return code


if __name__ == "__main__":
    sys.exit(main())
