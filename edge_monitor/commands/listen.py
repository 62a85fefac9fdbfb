"""edge-monitor listen: print what agents publish on Zenoh as JSON lines, for jq and scripts.

Subscribes to edge/<robot>/<joint>/<kind> and prints one JSON object per record on standard output:
the record as published, with "kind" (the key's last segment: symptom, alarm, advisory, friction,
health, or a kind added later) and "key" in front; each line validates against `edge-monitor schema
KIND`, which declares both; they are always those of the key, and a record whose own "robot" or
"joint" is not that of its key is not printed (counted as refused in the summary on standard error,
the first one logged). It first recovers what the agents' publishers still cache (off
with --no-history), then follows live until Ctrl-C or SIGTERM, --duration or --count. With both
--count and --duration it exits 1 when fewer than --count records came within --duration; with
--require-data-flowing also when a health record says the agent has no data (data_flowing false: no
decoded sample for data_timeout_s). The container's health check:
--kind health --count 1 --duration 30 --require-data-flowing.

Examples:
  edge-monitor listen --zenoh-mode client --zenoh-connect tcp/127.0.0.1:7447 --kind alarm
  edge-monitor listen --zenoh-connect tcp/127.0.0.1:7448 --robot cell7 --joint 2 --kind symptom \\
      | jq -c '{cycle, utc, wear: .wear.estimate}'
"""

from __future__ import annotations

import argparse
import logging
import queue
import sys
import time
from typing import Any

from edge_monitor.commands.common import (
    add_subscriber_arguments,
    add_zenoh_arguments,
    check_subscriber_arguments,
    zenoh_options,
)
from edge_monitor.records import to_json
from edge_monitor.run_failures import setup_failure
from edge_monitor.sinks.keys import KINDS, PREFIX, check_robot_name
from edge_monitor.sinks.zenoh_publisher import ReceivedRecord, SymptomSubscriber
from edge_monitor.sinks.zenoh_session import open_session
from protocol.console import EXIT_CODES_HELP, EXIT_FAILURE, UsageError, stop_on_signals, verbosity

log = logging.getLogger(__name__)

POLL_S = 0.1              # how often the main thread looks at the stop conditions
QUEUE_SIZE = 100_000      # bounded hand-over from Zenoh's thread; overflow is counted


def add_parser(subparsers: argparse._SubParsersAction) -> argparse.ArgumentParser:
    parser = subparsers.add_parser("listen", help="print symptoms, alarms and health from Zenoh as JSON lines",
                                   description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter,
                                   epilog=f"{EXIT_CODES_HELP}. Ctrl-C or SIGTERM is the normal end: exit code 0")
    add_zenoh_arguments(parser)
    parser.add_argument("--robot", default=None, help="only this robot (default: every robot)")
    parser.add_argument("--joint", type=int, action="append", default=[], metavar="N",
                        help="only this joint (repeatable; agent-level records such as health have no joint "
                             "and are left out)")
    parser.add_argument("--kind", action="append", default=[], metavar="KIND",
                        help="only records of this kind: symptom, alarm, friction, health, or any later kind "
                             "(repeatable; default: every kind)")
    add_subscriber_arguments(parser, "printed records")
    parser.add_argument("--require-data-flowing", action="store_true",
                        help="exit 1 if a health record printed says data_flowing false (a health check that fails "
                             "on a dead bus, not only on a dead agent)")
    parser.set_defaults(func=run)
    return parser


def key_expression(robot: str | None, joints: list[int], kinds: list[str]) -> str:
    """The narrowest key expression for the filters (several joints or kinds: a wildcard, then filtered)."""
    joint = str(joints[0]) if len(joints) == 1 else "*"
    kind = kinds[0] if len(kinds) == 1 else "*"
    return f"{PREFIX}/{robot or '*'}/{joint}/{kind}"


def selected(received: ReceivedRecord, joints: list[int], kinds: list[str]) -> bool:
    return (not joints or received.joint in joints) and (not kinds or received.kind in kinds)


def line_of(received: ReceivedRecord) -> str:
    """The printed line: "kind" and "key" of the key the record came on (never the record's own fields of
    those names), then the record."""
    record: dict[str, Any] = {"kind": received.kind, "key": received.key}
    record.update((name, value) for name, value in received.record.items() if name not in record)
    return to_json(record)


def mismatch(received: ReceivedRecord) -> str | None:
    """Why a record does not belong to the key it came on (its "robot" or "joint" is another's), or None.
    Such a record is not printed: any peer that may put on one robot's keys could otherwise speak for
    another (counted as "refused" in the summary on standard error)."""
    record = received.record
    if record.get("robot", received.robot) != received.robot:
        return f"robot {str(record.get('robot'))[:80]!r} on {received.key}"
    joint = record.get("joint", received.joint)
    if isinstance(joint, bool) or joint != received.joint:
        return f"joint {str(joint)[:20]} on {received.key}"
    return None


def _check(args: argparse.Namespace) -> None:
    if args.robot is not None:
        try:
            check_robot_name(args.robot)
        except ValueError as exc:
            raise UsageError(f"--robot: {exc}") from None
    for joint in args.joint:
        if not 0 <= joint <= 999:
            raise UsageError(f"--joint {joint}: a joint number is 0 … 999")
    for kind in args.kind:
        if not kind or any(c in kind for c in "/*$?# "):
            raise UsageError(f"--kind {kind!r}: one key segment such as symptom, alarm or health")
        if kind not in KINDS:               # kept: a newer agent may publish it
            log.warning("--kind %s: not a kind this version's agents publish (%s); waiting for it anyway",
                        kind, ", ".join(KINDS))
    check_subscriber_arguments(args)


def run(args: argparse.Namespace) -> int:
    _check(args)
    try:
        options = zenoh_options(args)
        session = open_session(options)
    except ValueError as exc:
        return setup_failure("listen", exc)
    key = key_expression(args.robot, args.joint, args.kind)
    inbox: queue.Queue[ReceivedRecord] = queue.Queue(maxsize=QUEUE_SIZE)
    dropped = refused = 0

    def enqueue(received: ReceivedRecord) -> None:
        nonlocal dropped, refused
        if selected(received, args.joint, args.kind):
            wrong = mismatch(received)
            if wrong is not None:
                refused += 1
                if refused == 1 or refused % 1000 == 0:
                    log.warning("record not printed: %s (%d refused so far)", wrong, refused)
                return
            try:
                inbox.put_nowait(received)
            except queue.Full:
                dropped += 1

    stop = stop_on_signals()
    subscriber = SymptomSubscriber(session, key, history=not args.no_history, callback=enqueue, keep=False)
    if verbosity(args) > 0:
        print(f"edge-monitor listen: subscribed to {key} ({options.describe()})", file=sys.stderr)
    printed = 0
    no_data: list[str] = []          # robots whose health record said data_flowing false
    deadline = None if args.duration is None else time.monotonic() + args.duration
    try:
        while not stop.is_set() and (args.count is None or printed < args.count):
            if deadline is not None and time.monotonic() >= deadline:
                break
            try:
                received = inbox.get(timeout=POLL_S)
            except queue.Empty:
                continue
            sys.stdout.write(line_of(received) + "\n")
            sys.stdout.flush()
            printed += 1
            if received.kind == "health" and received.record.get("data_flowing") is False:
                no_data.append(str(received.record.get("robot")))
    except BrokenPipeError:          # the reader went away (e.g. `| head`): a normal end
        sys.stderr.close()
    finally:
        subscriber.close()
        session.close()
    if verbosity(args) >= 0 and not sys.stderr.closed:
        print(f"edge-monitor listen: {printed} records printed; missed {subscriber.misses}, "
              f"undecodable {subscriber.decode_errors}, dropped {dropped}, refused {refused} (robot or joint "
              "not that of the key)", file=sys.stderr)
    if args.count is not None and args.duration is not None and printed < args.count and not stop.is_set() \
            and not sys.stderr.closed:
        print(f"edge-monitor listen: {printed} of --count {args.count} records within --duration "
              f"{args.duration:g} s", file=sys.stderr)
        return EXIT_FAILURE
    if args.require_data_flowing and no_data:
        if not sys.stderr.closed:
            print(f"edge-monitor listen: no data flowing at {', '.join(sorted(set(no_data)))} (health data_flowing "
                  "false: no decoded sample for data_timeout_s)", file=sys.stderr)
        return EXIT_FAILURE
    return 0
