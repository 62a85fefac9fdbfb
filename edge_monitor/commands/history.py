"""edge-monitor history: ask the plant's history, from the historian over Zenoh (edge/history/**) or
straight from its database (--db), and print JSON lines (default), CSV or one JSON document.

  edge-monitor history --zenoh-mode client --zenoh-connect tcp/127.0.0.1:7447 --robot r1 --kind symptom --since 7d
  edge-monitor history --db plant.db --open-alarms
  edge-monitor history --db plant.db --fleet --rank forecast --format csv     (joints ranked by the forecast)
  edge-monitor history --db plant.db --gaps --robot r1                        (cycles missing, per joint)

Records come out as published, with "kind" in front, oldest first, at most --limit (the historian pages
by 1 000; a note on stderr says when more matched). A robot the history has never heard of prints
nothing and says so on stderr. Times: ISO 8601 (2026-11-26, 2026-11-26T13:00Z) or an age (30m, 24h, 7d).
"""

from __future__ import annotations

import argparse
import csv
import sys
from typing import Any, Iterator

from edge_monitor.commands.common import add_tls_arguments, add_zenoh_arguments, print_json
from edge_monitor.commands.historian import add_database_arguments, database_target
from edge_monitor.historian.client import HistoryRefused, HistoryUnavailable, database_asker, pages, zenoh_asker
from edge_monitor.historian.database import DatabaseError, connect
from edge_monitor.historian.identity import STORED_KINDS
from edge_monitor.historian.query_spec import MAX_FLEET_LIMIT, RANKS, HistoryQuery, QueryError
from edge_monitor.historian.times import TimeFormatError, parse_age, parse_time
from edge_monitor.records import to_json
from edge_monitor.run_failures import setup_failure
from protocol.console import EXIT_CODES_HELP, EXIT_FAILURE, UsageError

NAME = "edge-monitor history"
FORMATS = ("jsonl", "csv", "json")
COLUMNS = {
    "records": ("kind", "robot", "joint", "cycle", "utc", "wear.estimate", "wear.std", "alarm", "state", "fault",
                "quantity"),
    "fleet": ("rank", "robot", "joint", "cycle", "utc", "wear.estimate", "wear.band.0", "wear.band.1",
              "forecast_days", "alarm", "open_faults", "last_maintenance.utc", "last_heard", "stale", "online"),
    "gaps": ("robot", "joint", "first", "last", "missing", "after_utc", "before_utc"),
    "daily": ("robot", "joint", "day", "records", "first_cycle", "last_cycle", "wear.min", "wear.mean", "wear.max",
              "alarm_records"),
}
COLUMNS["alarms"] = COLUMNS["records"]


def add_parser(subparsers: argparse._SubParsersAction) -> argparse.ArgumentParser:
    p = subparsers.add_parser("history", help="ask the plant's history (records, open alarms, the fleet, gaps)",
                              description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter,
                              epilog=f"{EXIT_CODES_HELP}; 1 also when no historian answered")
    what = p.add_mutually_exclusive_group()
    what.add_argument("--open-alarms", action="store_true", help="the newest record of every open fault")
    what.add_argument("--fleet", action="store_true",
                      help="per joint: newest wear and band, forecast, open faults, last maintenance, last heard")
    what.add_argument("--gaps", action="store_true", help="cycles missing from the history, per joint")
    what.add_argument("--daily", action="store_true", help="daily summaries of thinned days")
    add_query_arguments(p)
    p.add_argument("--rank", choices=RANKS, default="wear", help="--fleet: order by wear (highest first), by the "
                                                                 "forecast (soonest first) or by robot")
    p.add_argument("--stale", default="1h", help="--fleet: an agent silent this long is stale (30m, 1h, 2d)")
    p.add_argument("--limit", type=int, default=1000, help="at most this many records (or joints)")
    p.add_argument("--format", choices=FORMATS, default="jsonl",
                   help="jsonl: one JSON object a line; csv: a header and the main fields; json: the whole answer")
    p.add_argument("--timeout", type=float, default=10.0, metavar="S", help="wait at most S s for the historian")
    add_database_arguments(p)
    add_zenoh_arguments(p)
    add_tls_arguments(p, "a reader")
    p.set_defaults(func=run)
    return p


def add_query_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--robot", default=None, help="only this robot")
    parser.add_argument("--joint", type=int, default=None, help="only this joint")
    parser.add_argument("--kind", action="append", default=[], choices=STORED_KINDS,
                        help="only records of this kind (repeatable; default: every kind)")
    parser.add_argument("--since", default=None, help="from this time on (ISO 8601 or an age: 7d)")
    parser.add_argument("--until", default=None, help="before this time")


def query_of_args(args: argparse.Namespace) -> HistoryQuery:
    what = ("alarms" if args.open_alarms else "fleet" if args.fleet else "gaps" if args.gaps
            else "daily" if args.daily else "records")
    top = MAX_FLEET_LIMIT if what == "fleet" else 10 ** 9
    if not 1 <= args.limit <= top:
        raise UsageError(f"--limit {args.limit}: 1 … {top}")
    try:
        return HistoryQuery(what=what, robot=args.robot, joint=args.joint, kinds=tuple(args.kind),
                            since=None if args.since is None else parse_time(args.since),
                            until=None if args.until is None else parse_time(args.until),
                            limit=min(args.limit, MAX_FLEET_LIMIT if what == "fleet" else 1000),
                            rank=getattr(args, "rank", "wear"), stale_s=parse_age(getattr(args, "stale", "1h")))
    except (QueryError, TimeFormatError) as exc:
        raise UsageError(str(exc)) from None


def asker(args: argparse.Namespace) -> tuple[Any, Any]:
    """(ask, closer): the database when ``--db``/``--db-url-file`` is given, else the historian over Zenoh."""
    if args.db is not None or args.db_url_file is not None:
        conn = connect(database_target(args), create=False)
        return database_asker(conn), conn.close
    from edge_monitor.commands.common import zenoh_options_with_tls
    from edge_monitor.sinks.zenoh_session import open_session
    if not 0 < args.timeout <= 600:
        raise UsageError(f"--timeout {args.timeout:g}: > 0 and at most 600 s")
    session = open_session(zenoh_options_with_tls(args))
    return zenoh_asker(session, args.timeout), session.close


def run(args: argparse.Namespace) -> int:
    query = query_of_args(args)
    try:
        ask, close = asker(args)
    except (DatabaseError, ValueError) as exc:      # ZenohSetupError/ZenohUnavailable are ValueErrors
        if isinstance(exc, UsageError):
            raise
        return setup_failure("history", exc) if not isinstance(exc, DatabaseError) else _failed(exc)
    try:
        answers = list(pages(ask, query, args.limit)) if query.what == "records" else [ask(query)]
    except (HistoryUnavailable, DatabaseError) as exc:
        return _failed(exc)
    except HistoryRefused as exc:
        raise UsageError(str(exc)) from None
    finally:
        close()
    try:
        _print(answers, args.format)
    except BrokenPipeError:          # the reader went away (`| head`): a normal end
        sys.stderr.close()
        return 0
    last = answers[-1]
    if last.get("message"):
        print(f"{NAME}: {last['message']}", file=sys.stderr)
    if last.get("truncated"):
        print(f"{NAME}: more matched than --limit {args.limit}: narrow --since/--until or raise --limit",
              file=sys.stderr)
    return 0


def _failed(exc: Exception) -> int:
    print(f"{NAME}: {exc}", file=sys.stderr)
    return EXIT_FAILURE


def items(answer: dict[str, Any]) -> list[dict[str, Any]]:
    return answer.get("records") or answer.get("joints") or answer.get("gaps") or []


def _print(answers: list[dict[str, Any]], fmt: str) -> None:
    if fmt == "json":
        merged = dict(answers[-1])
        key = "joints" if "joints" in merged else "gaps" if "gaps" in merged else "records"
        merged[key] = [item for a in answers for item in items(a)]
        merged["count"] = len(merged[key])
        print_json(merged)
        return
    rows = (item for a in answers for item in items(a))
    if fmt == "jsonl":
        for item in rows:
            sys.stdout.write(to_json(item) + "\n")
        return
    columns = COLUMNS[answers[0]["answer"]]
    writer = csv.writer(sys.stdout, lineterminator="\n")
    writer.writerow(columns)
    for item in rows:
        writer.writerow([_cell(item, column) for column in columns])


def _cell(item: dict[str, Any], column: str) -> Any:
    value: Any = item
    for part in column.split("."):
        if isinstance(value, list) and part.isdigit():
            value = value[int(part)] if int(part) < len(value) else None
        else:
            value = value.get(part) if isinstance(value, dict) else None
    if isinstance(value, list):
        return " ".join(str(v.get("fault", v)) if isinstance(v, dict) else str(v) for v in value)
    return "" if value is None else value


def history_records(ask: Any, query: HistoryQuery, wanted: int) -> Iterator[dict[str, Any]]:
    """Every record of ``query`` (paged), for drawing (``view --history``)."""
    for answer in pages(ask, query, wanted):
        yield from items(answer)
