"""edge-monitor historian: the plant's memory. Subscribes through the Zenoh router to every agent's
symptoms, alarms, advisories, friction curves and health, stores each exactly once in SQLite (one file)
or PostgreSQL, and answers history questions on edge/history/** (edge-monitor history).

  edge-monitor historian --db plant.db --zenoh-mode client --zenoh-connect tcp/127.0.0.1:7447
  edge-monitor historian import r1.jsonl r1.jsonl.1 --db plant.db      (idempotent: fills gaps)
  edge-monitor historian gaps --db plant.db --since 7d                 (cycles missing, per joint)
  edge-monitor historian thin --db plant.db --keep-days 180            (retention now; the service thins hourly)

--db takes a file path or postgresql://user@host/dbname; the password never goes on the command line:
PGPASSWORD, PGPASSFILE (~/.pgpass) or --db-url-file FILE (mode 600). The service prints "historian
ready" on standard error once it listens, runs until Ctrl-C or SIGTERM (or --duration), then stores what
it holds (with --json, standard output is the final status as one JSON object, nothing else).
"""

from __future__ import annotations

import argparse
import logging
import sys
import time

from edge_monitor.commands.common import (
    add_tls_arguments,
    add_zenoh_arguments,
    print_json,
    zenoh_options_with_tls,
)
from edge_monitor.historian.database import DatabaseError, connect
from edge_monitor.historian.db_url import DatabaseUrlError, DbTarget, parse_db, read_url_file
from edge_monitor.historian.gaps import describe_gaps, find_gaps
from edge_monitor.historian.identity import HealthSampling
from edge_monitor.historian.migrations import SchemaTooNew
from edge_monitor.historian.retention import Retention, thin
from edge_monitor.historian.times import TimeFormatError, parse_time
from edge_monitor.historian.writer import DEFAULT_QUEUE, LOST
from edge_monitor.run_failures import setup_failure
from protocol.console import EXIT_CODES_HELP, EXIT_FAILURE, UsageError, stop_on_signals, verbosity

log = logging.getLogger(__name__)

NAME = "edge-monitor historian"
ACTIONS = ("serve", "import", "gaps", "thin")
STATUS_EVERY_S = 60.0


def add_parser(subparsers: argparse._SubParsersAction) -> argparse.ArgumentParser:
    p = subparsers.add_parser("historian", help="store every agent's records in SQLite or PostgreSQL, answer "
                                                "history queries", description=__doc__,
                              formatter_class=argparse.RawDescriptionHelpFormatter,
                              epilog=f"{EXIT_CODES_HELP}. Ctrl-C or SIGTERM is the normal end of the service: exit 0")
    p.add_argument("action", nargs="?", default="serve", choices=ACTIONS,
                   help="serve (default): the service; import PATH…: JSONL files; gaps; thin")
    p.add_argument("paths", nargs="*", metavar="PATH", help="import: the agents' JSONL files")
    add_database_arguments(p)
    p.add_argument("--keep-days", type=float, default=Retention().keep_days,
                   help="per-cycle records are kept this many days, then thinned to daily summaries (0: for ever)")
    p.add_argument("--health-every", type=float, default=HealthSampling().every_s, metavar="S",
                   help="one health record per robot and S seconds is stored (the newest always)")
    p.add_argument("--queue", type=int, default=DEFAULT_QUEUE, metavar="N",
                   help="records waiting for the database at most (more are lost, counted with their ranges)")
    p.add_argument("--no-history", action="store_true",
                   help="do not ask the agents' caches on start (only what is published from now on)")
    p.add_argument("--since", default="1d", help="gaps: look this far back (an age like 7d, or ISO 8601)")
    p.add_argument("--duration", type=float, default=None, metavar="S", help="serve: stop after S seconds")
    p.add_argument("--json", action="store_true", help="print the final status / import report as JSON")
    add_zenoh_arguments(p)
    add_tls_arguments(p, "the historian")
    p.set_defaults(func=run)
    return p


def add_database_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--db", default=None, metavar="URL",
                        help="a SQLite file (plant.db) or postgresql://user@host[:port]/dbname (no password here)")
    parser.add_argument("--db-url-file", default=None, metavar="FILE",
                        help="read the database URL (it may hold a password) from FILE, readable by its owner only")


def database_target(args: argparse.Namespace) -> DbTarget:
    """The database ``--db`` / ``--db-url-file`` name; UsageError when neither or both, or a bad one."""
    if (args.db is None) == (args.db_url_file is None):
        raise UsageError("give the database: --db plant.db (or postgresql://user@host/dbname), or --db-url-file FILE")
    try:
        return parse_db(args.db) if args.db is not None else read_url_file(args.db_url_file)
    except DatabaseUrlError as exc:
        raise UsageError(str(exc)) from None


def run(args: argparse.Namespace) -> int:
    target = database_target(args)
    try:
        retention = Retention(args.keep_days)
        sampling = HealthSampling(args.health_every)
    except ValueError as exc:
        raise UsageError(str(exc)) from None
    if args.action != "import" and args.paths:
        raise UsageError(f"{args.action} takes no PATH (only import does)")
    if args.action == "serve":
        return _serve(args, target, retention, sampling)
    try:
        conn = connect(target, create=args.action == "import")
    except (DatabaseError, SchemaTooNew) as exc:
        print(f"{NAME}: {exc}", file=sys.stderr)
        return EXIT_FAILURE
    try:
        if args.action == "import":
            return _import(args, conn)
        if args.action == "gaps":
            return _gaps(args, conn)
        result = thin(conn, retention)
        print(f"{NAME}: {result.days} day(s) thinned, {result.removed} records removed, "
              f"{result.summaries} daily summaries written", flush=True)
        return 0
    except DatabaseError as exc:
        print(f"{NAME}: {exc}", file=sys.stderr)
        return EXIT_FAILURE
    finally:
        conn.close()


def _import(args: argparse.Namespace, conn) -> int:
    from edge_monitor.historian.jsonl_import import import_files
    if not args.paths:
        raise UsageError("import needs the JSONL file(s): historian import r1.jsonl [r1.jsonl.1 …] --db …")
    report = import_files(conn, args.paths)
    gaps = find_gaps(conn, since=report.span[0]) if report.span else []
    gaps = [g for g in gaps if g["robot"] in report.robots]
    if args.json:
        print_json({**report.to_dict(), "gaps": gaps})
    else:
        bad = sum(report.bad_lines.values())
        print(f"{NAME} import: {report.files} file(s), {report.lines} lines: {report.stored} records stored, "
              f"{report.duplicates} already there, {report.expired} older than the retention, {bad} bad line(s)"
              + (f" ({'; '.join(report.examples)})" if bad else ""), flush=True)
        if gaps:
            print(f"cycles still missing:\n{describe_gaps(gaps)}", flush=True)
    for problem in report.unreadable:
        print(f"{NAME} import: cannot read {problem}", file=sys.stderr)
    return EXIT_FAILURE if report.unreadable else 0


def _gaps(args: argparse.Namespace, conn) -> int:
    try:
        since = parse_time(args.since)
    except TimeFormatError as exc:
        raise UsageError(f"--since: {exc}") from None
    gaps = find_gaps(conn, since=since)
    if args.json:
        print_json({"gaps": gaps, "missing": sum(g["missing"] for g in gaps)})
    else:
        print(describe_gaps(gaps, shown=len(gaps)) if gaps else "no cycles missing", flush=True)
    return 0


def _serve(args: argparse.Namespace, target: DbTarget, retention: Retention, sampling: HealthSampling) -> int:
    from edge_monitor.historian.service import Historian, HistorianConfig
    from edge_monitor.sinks.zenoh_session import ZenohSetupError, open_session
    if args.duration is not None and not args.duration > 0:
        raise UsageError(f"--duration {args.duration}: must be > 0 s")
    try:
        config = HistorianConfig(retention=retention, health=sampling, queue_size=args.queue,
                                 history=not args.no_history)
        options = zenoh_options_with_tls(args)
    except ZenohSetupError as exc:
        raise UsageError(str(exc)) from None
    except ValueError as exc:
        raise UsageError(str(exc)) from None
    stop = stop_on_signals()
    try:
        session = open_session(options)
    except ZenohSetupError as exc:       # ZenohUnavailable: valid options, no router: exit 1
        return setup_failure("historian", exc)
    try:
        historian = Historian(session, target, config).start()
    except (DatabaseError, SchemaTooNew) as exc:
        session.close()
        print(f"{NAME}: {exc}", file=sys.stderr)
        return EXIT_FAILURE
    except BaseException:
        session.close()
        raise
    print(f"historian ready: storing into {target.describe()}, subscribed to edge/** ({options.describe()}), "
          "answering edge/history/**", file=sys.stderr, flush=True)       # stdout: only the --json summary
    deadline = None if args.duration is None else time.monotonic() + args.duration
    next_status = time.monotonic() + STATUS_EVERY_S
    try:
        while not stop.wait(0.2):
            historian.tick()
            if deadline is not None and time.monotonic() >= deadline:
                break
            if historian.unusable is not None:         # logged by the writer; no retry mends it
                print(f"{NAME}: stopping: the database can store nothing more (logged above with what to do)",
                      file=sys.stderr, flush=True)
                break
            if time.monotonic() >= next_status:
                next_status += STATUS_EVERY_S
                _log_status(historian.status())
    finally:
        status = historian.close()
        session.close()
    if args.json:
        print_json(status)
    elif verbosity(args) >= 0:
        print(f"historian stopped: received {status['received']}, stored {status.get('stored', 0)}, duplicates "
              f"{status.get('duplicates', 0)}, rejected {sum(status['rejected'].values())}, lost "
              f"{status['lost']}{lost_reasons(status)}", file=sys.stderr, flush=True)
    return EXIT_FAILURE if status["lost"] or status.get("queue_depth") or status.get("database_unusable") else 0


def lost_reasons(status: dict) -> str:
    """`` (queue full 3, database unusable 86)``: the reasons of the summary's lost records."""
    parts = [f"{text} {status[name]}" for name, text in LOST.items() if status.get(name)]
    return f" ({', '.join(parts)})" if parts else ""


def _log_status(status: dict) -> None:
    log.info("historian: received %d, stored %d, duplicates %d, queue %d, agents online %d%s", status["received"],
             status.get("stored", 0), status.get("duplicates", 0), status["queue_depth"], len(status["agents_online"]),
             "" if status["database_down_s"] is None else f", database down for {status['database_down_s']} s")
