"""``edge-monitor view --history --robot R``: a robot's past from the historian, drawn in Rerun as a live
agent's records would be (symptoms on the cycle timeline, alarm events in each joint's log)."""

from __future__ import annotations

import argparse
import sys

from edge_monitor.historian.client import HistoryRefused, HistoryUnavailable
from edge_monitor.historian.database import DatabaseError
from edge_monitor.run_failures import setup_failure
from protocol.console import EXIT_FAILURE, UsageError

#: Most records one view draws (a robot's year: 6 joints × 300 cycles × 365 ≈ 660 000).
MAX_RECORDS = 2_000_000


def add_history_view_arguments(parser: argparse.ArgumentParser) -> None:
    group = parser.add_argument_group("history", "draw the past from the historian (docs/HISTORIAN.md)")
    group.add_argument("--history", action="store_true",
                       help="draw --robot's stored records (from the historian over Zenoh, or --db) and exit")
    group.add_argument("--since", default=None, help="from this time on (ISO 8601 or an age: 30d)")
    group.add_argument("--until", default=None, help="before this time")
    group.add_argument("--joint", type=int, default=None, help="only this joint")
    group.add_argument("--db", default=None, metavar="URL", help="read the history database directly")
    group.add_argument("--db-url-file", default=None, metavar="FILE", help="its URL from a file (mode 600)")
    group.add_argument("--timeout", type=float, default=10.0, metavar="S", help="wait at most S s for the historian")
    group.add_argument("--limit", type=int, default=MAX_RECORDS, help=argparse.SUPPRESS)


def draw_history(args: argparse.Namespace) -> int:
    from edge_monitor.commands.history import asker, history_records, query_of_args
    from edge_monitor.sinks.rerun_view import SAVE_BATCHING, RerunSink
    if args.robot is None:
        raise UsageError("--history needs --robot: whose past to draw")
    args.kind, args.open_alarms, args.fleet, args.gaps, args.daily = ["symptom", "alarm"], False, False, False, False
    query = query_of_args(args)
    try:
        sink = RerunSink.open(args.rerun, fallback_save=f"{args.robot}-history.rrd", batching=SAVE_BATCHING)
    except ValueError as exc:
        return setup_failure("view", exc)
    symptoms = alarms = 0
    try:
        ask, close = asker(args)
        try:
            for record in history_records(ask, query, args.limit):
                if record.pop("kind") == "alarm":
                    sink.log_alarm(record)
                    alarms += 1
                else:
                    sink.log_symptoms([record])
                    symptoms += 1
        finally:
            close()
    except (HistoryUnavailable, DatabaseError) as exc:
        print(f"edge-monitor view: {exc}", file=sys.stderr)
        return EXIT_FAILURE
    except HistoryRefused as exc:
        raise UsageError(str(exc)) from None
    except ValueError as exc:           # ZenohSetupError / ZenohUnavailable
        return setup_failure("view", exc)
    finally:
        sink.close()
    print(f"edge-monitor view: {symptoms} symptoms and {alarms} alarm records of {args.robot} drawn to {sink.spec}",
          flush=True)
    return 0
