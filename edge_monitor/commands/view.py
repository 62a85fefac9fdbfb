"""``edge-monitor view``: subscribe to ``edge/**`` over Zenoh and draw every robot and joint in Rerun;
with ``--history``, draw a robot's past from the historian instead (docs/HISTORIAN.md).

The fleet view, for a workstation: recovers what the agents' publishers still cache, then follows
live. Stops on SIGINT/SIGTERM, after ``--duration`` seconds or after ``--count`` symptom records.
"""

from __future__ import annotations

import argparse
import logging
import queue
import sys
import time

from edge_monitor.commands.common import (
    add_subscriber_arguments,
    add_zenoh_arguments,
    check_subscriber_arguments,
    zenoh_options,
)
from edge_monitor.commands.history_view import add_history_view_arguments, draw_history
from edge_monitor.run_failures import setup_failure
from edge_monitor.sinks.keys import ALARM, HEALTH, SYMPTOM, check_robot_name
from edge_monitor.sinks.rerun_view import LIVE_BATCHING, RerunSink
from edge_monitor.sinks.zenoh_publisher import ReceivedRecord, SymptomSubscriber
from edge_monitor.sinks.zenoh_session import ZenohSetupError, open_session
from protocol.console import EXIT_CODES_HELP, stop_on_signals

log = logging.getLogger(__name__)

DRAW_PERIOD_S = 0.1       # records arriving within this period are drawn as one block
QUEUE_SIZE = 100_000      # bounded hand-over from Zenoh's thread; overflow is counted


def add_parser(subparsers: argparse._SubParsersAction) -> argparse.ArgumentParser:
    parser = subparsers.add_parser("view", help="draw the symptoms of any number of robots in Rerun",
                                   description=__doc__.replace("``", ""),
                                   epilog=f"{EXIT_CODES_HELP}. Ctrl-C or SIGTERM is the normal end of a view: "
                                          "exit code 0")
    add_zenoh_arguments(parser)
    parser.add_argument("--robot", default=None, help="only this robot (default: every robot under edge/)")
    parser.add_argument("--rerun", default="spawn", metavar="SPEC",
                        help="save:PATH | spawn | connect[:URL] (default spawn; without a display: "
                             "save:edge-view.rrd)")
    add_subscriber_arguments(parser, "symptom records")
    add_history_view_arguments(parser)
    parser.set_defaults(func=run)
    return parser


class _Counts:
    def __init__(self) -> None:
        self.symptoms = 0
        self.alarms = 0
        self.health = 0
        self.dropped = 0
        self.malformed = 0
        self.joints: set[tuple[str, int]] = set()


def run(args: argparse.Namespace) -> int:
    check_subscriber_arguments(args)
    if args.history:
        return draw_history(args)
    try:
        if args.robot is not None:
            check_robot_name(args.robot)
        options = zenoh_options(args)
        # a live display, also when saving: what arrived within a second is drawn as one block
        sink = RerunSink.open(args.rerun, fallback_save="edge-view.rrd", batching=LIVE_BATCHING)
    except ValueError as exc:       # ZenohSetupError, RerunSetupError, a bad robot name
        return setup_failure("view", exc)
    if sink.fallback_reason:
        print(f"edge-monitor view: {sink.fallback_reason}; drawing to {sink.spec}", file=sys.stderr)
    try:
        session = open_session(options)
    except ZenohSetupError as exc:
        sink.close()
        return setup_failure("view", exc)

    stop = stop_on_signals()
    inbox: queue.Queue[ReceivedRecord] = queue.Queue(maxsize=QUEUE_SIZE)
    counts = _Counts()

    def enqueue(received: ReceivedRecord) -> None:
        try:
            inbox.put_nowait(received)
        except queue.Full:
            counts.dropped += 1

    key_expr = f"edge/{args.robot}/**" if args.robot else "edge/**"
    subscriber = SymptomSubscriber(session, key_expr, history=not args.no_history, callback=enqueue, keep=False)
    print(f"edge-monitor view: subscribed to {key_expr} ({options.describe()}), drawing to {sink.spec}",
          flush=True)
    deadline = None if args.duration is None else time.monotonic() + args.duration
    try:
        while not stop.is_set():
            _draw_pending(inbox, sink, counts)
            if args.count is not None and counts.symptoms >= args.count:
                break
            if deadline is not None and time.monotonic() >= deadline:
                break
            stop.wait(DRAW_PERIOD_S)
        _draw_pending(inbox, sink, counts)
    finally:
        subscriber.close()
        session.close()
        sink.close()
    robots = sorted({robot for robot, _ in counts.joints})
    print(f"edge-monitor view: {counts.symptoms} symptoms from {len(robots)} robot(s) "
          f"({', '.join(robots) or '-'}), {len(counts.joints)} joint(s), {counts.alarms} alarm records, "
          f"{counts.health} health records; missed {subscriber.misses}, undecodable {subscriber.decode_errors}, "
          f"dropped {counts.dropped}, malformed {counts.malformed}, drawing errors {sink.errors}; sink {sink.spec}",
          flush=True)
    return 0


def _draw_pending(inbox: queue.Queue, sink: RerunSink, counts: _Counts) -> None:
    """Drain the inbox: symptoms drawn as one block (send_columns), alarms and health one by one."""
    symptoms = []
    while True:
        try:
            received: ReceivedRecord = inbox.get_nowait()
        except queue.Empty:
            break
        if received.kind in (SYMPTOM, ALARM) and received.joint is None:
            counts.malformed += 1           # e.g. edge/<robot>/agent/symptom: not a joint key
        elif received.kind == SYMPTOM and received.joint is not None:
            symptoms.append({"robot": received.robot, "joint": received.joint, **received.record})
            counts.joints.add((received.robot, received.joint))
        elif received.kind == ALARM:
            sink.log_alarm({"robot": received.robot, "joint": received.joint, **received.record})
            counts.alarms += 1
        elif received.kind == HEALTH:
            sink.log_health(received.record, robot=received.robot)
            counts.health += 1
    if symptoms:
        sink.log_symptoms(symptoms)
        counts.symptoms += len(symptoms)
