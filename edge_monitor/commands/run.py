"""``edge-monitor run --link LINK``: the agent beside a controller, live.

Receives frames from a CAN link, publishes per-cycle symptoms over Zenoh (and optionally JSONL and
Rerun), persists learned models in ``--state-dir`` and shuts down cleanly on SIGINT/SIGTERM
(state saved, Zenoh undeclared, Rerun flushed; exit code 0: the normal end of a monitor that runs
until stopped, 1 if records could not be written meanwhile: a full disk under the JSONL file or the
state, counted in ``sink_errors`` and ``state_save_errors`` while monitoring went on). SIGHUP makes
the JSONL output reopen its path (logrotate). The status line (every ``status_interval_s``) is
logged at INFO (``-v``); a final line says why it stopped; ``--json`` prints the run summary (the
same as replay's, with the reason it stopped and the last health record) as one JSON line on
standard output.
"""

from __future__ import annotations

import argparse
import dataclasses
import logging
import math
import signal
import sys
import threading
from contextlib import ExitStack

from edge_monitor.app import App, Outputs, build_app
from edge_monitor.commands.common import (
    add_config_arguments,
    add_zenoh_arguments,
    load_agent_config,
    open_mapped_source,
    open_state_store,
    prognosis_summary,
    zenoh_options,
)
from edge_monitor.pipeline.live import LiveRunner
from edge_monitor.records import to_json
from edge_monitor.run_failures import output_failures, setup_failure
from edge_monitor.sinks.base import LastSymptomSink
from edge_monitor.sinks.jsonl import JsonlOpenError
from edge_monitor.sources.frame_source import LiveSource
from protocol.console import (
    EXIT_CODES_HELP,
    EXIT_FAILURE,
    UsageError,
    add_can_arguments,
    can_options,
    verbosity,
)

log = logging.getLogger(__name__)

#: Longest --duration / --idle-stop accepted [s] (about 31 years).
MAX_SECONDS = 1e9


def add_parser(subparsers: argparse._SubParsersAction) -> None:
    p = subparsers.add_parser("run", help="monitor a live CAN link", description=__doc__,
                              formatter_class=argparse.RawDescriptionHelpFormatter,
                              epilog=f"{EXIT_CODES_HELP}. Ctrl-C or SIGTERM is the normal end of a run: "
                                     "state saved, exit code 0")
    add_can_arguments(p, "socketcan:IFACE | slcan:DEVICE_OR_URL | virtual:NAME "
                         "(omit to use -i/-c/-b or python-can's CAN_*/~/.canrc config)")
    add_config_arguments(p)
    add_zenoh_arguments(p)
    p.add_argument("--no-zenoh", action="store_true", help="do not publish over Zenoh")
    p.add_argument("--rerun", default=None, help="off | save:PATH | spawn | connect:URL (default: config, off)")
    p.add_argument("--duration", type=float, help="stop after this many seconds")
    p.add_argument("--max-cycles", type=int, help="stop after this many cycles")
    p.add_argument("--idle-stop", type=float,
                   help="stop after this many seconds without frames: the end of the stream, which closes and "
                        "publishes the last cycle, like replay at the end of a file (unless --no-close)")
    p.add_argument("--no-close", action="store_true",
                   help="at the end of the stream (--idle-stop) leave the last cycle open, as replay --no-close")
    p.add_argument("--maintenance", type=int, action="append", default=[], metavar="JOINT",
                   help="declare a gearbox replacement / service on JOINT at start: relearn its nominal models")
    p.add_argument("--json", action="store_true",
                   help="at the end, print the run summary as one JSON line on stdout (schema: edge-monitor schema "
                        "summary)")
    p.add_argument("--summary-json", dest="json", action="store_true", help=argparse.SUPPRESS)   # its old name
    p.add_argument("--allow-remote-maintenance", action="store_true",
                   help="accept maintenance declarations put on Zenoh key edge/<robot>/<joint>/maintenance "
                        "(off by default; rate-limited; restrict who may put with a Zenoh ACL, docs/SECURITY.md)")
    p.add_argument("--allow-remote-acknowledge", action="store_true",
                   help="accept alarm acknowledgements put on Zenoh key edge/<robot>/<joint>/acknowledge "
                        "(`edge-monitor acknowledge`; off by default; rate-limited; docs/SECURITY.md)")
    p.set_defaults(func=run)


def install_signal_handlers(stop: threading.Event) -> None:
    def handler(signum, _frame):
        log.warning("signal %d: stopping (state is saved)", signum)
        stop.set()
    if threading.current_thread() is threading.main_thread():
        signal.signal(signal.SIGINT, handler)
        signal.signal(signal.SIGTERM, handler)


def stop_text(runner: LiveRunner, args: argparse.Namespace) -> str:
    """Why the runner stopped, in the words of the options."""
    reason = runner.stop_reason
    if reason == "idle":
        return f"the bus was idle for {args.idle_stop:g} s (--idle-stop)"
    if reason == "duration":
        return f"--duration {args.duration:g} s reached"
    if reason == "max_cycles":
        return f"--max-cycles {args.max_cycles} reached"
    return "signal" if reason == "stopped" else "end of the frame stream"


def final_line(runner: LiveRunner, args: argparse.Namespace) -> str:
    h = runner.health().counters
    return (f"edge-monitor run: stopped: {stop_text(runner, args)}; {h['frames_total']} frames (ok {h['frames_ok']}), "
            f"{h['cycles']} cycles, {h['symptoms']} symptoms, {h['alarms']} alarms")


def check_limits(args: argparse.Namespace) -> None:
    """``--duration``/``--idle-stop`` finite and > 0, ``--max-cycles`` ≥ 1 (else UsageError)."""
    for name in ("duration", "idle_stop"):
        value = getattr(args, name)
        if value is not None and not (math.isfinite(value) and 0 < value <= MAX_SECONDS):
            raise UsageError(f"--{name.replace('_', '-')} {value}: give a number of seconds in (0, {MAX_SECONDS:g}]")
    if args.max_cycles is not None and args.max_cycles < 1:
        raise UsageError(f"--max-cycles {args.max_cycles}: give a number of cycles ≥ 1")


def install_reopen_on_hangup(app: App) -> None:
    """SIGHUP (logrotate's postrotate): the JSONL output reopens its path before its next record."""
    from edge_monitor.sinks.jsonl import JsonlSink
    sinks = [s for s in app.sinks if isinstance(s, JsonlSink)]
    if sinks and hasattr(signal, "SIGHUP") and threading.current_thread() is threading.main_thread():
        def handler(_signum, _frame):
            for sink in sinks:
                sink.request_reopen()
        signal.signal(signal.SIGHUP, handler)


def run(args: argparse.Namespace) -> int:
    from protocol.links import LinkError, LinkUsageError, is_log_file, open_bus
    if args.link and is_log_file(args.link):
        raise UsageError(f"--link {args.link} is a log file; use `edge-monitor replay {args.link}`")
    check_limits(args)
    cfg, source = open_mapped_source(load_agent_config(args), args.mapping)
    if args.allow_remote_maintenance:
        cfg = dataclasses.replace(cfg, maintenance=dataclasses.replace(cfg.maintenance, remote=True))
    if args.allow_remote_acknowledge:
        cfg = dataclasses.replace(cfg, acknowledge=dataclasses.replace(cfg.acknowledge, remote=True))
    store = open_state_store(cfg)
    with ExitStack() as stack:
        try:
            outputs = Outputs(jsonl=cfg.jsonl, zenoh=None if args.no_zenoh else zenoh_options(args),
                              rerun=args.rerun or cfg.rerun, rerun_fallback="edge-monitor.rrd", maintenance=True)
            app = build_app(cfg, outputs, stack, store, live=True, source=source)
        except (ValueError, JsonlOpenError) as exc:   # ZenohSetupError, RerunSetupError, a bad robot name,
            return setup_failure("run", exc)          # a JSONL file that cannot be opened
        agent = app.agent
        last = LastSymptomSink()             # each joint's last prognosis, for the --json summary
        agent.sinks.append(last)
        install_reopen_on_hangup(app)
        for joint in args.maintenance:
            try:
                agent.declare_maintenance(joint)
            except ValueError as exc:
                raise UsageError(f"--maintenance {joint}: {exc}") from None
        try:
            bus = open_bus(args.link, **can_options(args))
        except LinkUsageError as exc:     # a bad link or interface name, no CAN configured: exit 2
            raise UsageError(str(exc)) from None
        except LinkError as exc:
            print(f"edge-monitor run: cannot open the CAN link: {exc}", file=sys.stderr)
            return EXIT_FAILURE
        stack.callback(bus.shutdown)
        runner = LiveRunner(agent, LiveSource(bus, maxsize=cfg.queue_size, block_size=cfg.block_size),
                            status_interval_s=cfg.status_interval_s, extra_counters=app.extra_counters,
                            data_timeout_s=cfg.data_timeout_s)
        install_signal_handlers(runner.stop_event)
        runner.run(duration_s=args.duration, max_cycles=args.max_cycles, idle_stop_s=args.idle_stop)
        if runner.stop_reason == "idle" and not args.no_close:
            # the stream ended (docs/OUTPUTS.md "End of the stream"): its last cycle is complete, publish it
            # as replay does at the end of a file; a stop mid-stream (signal, --duration, --max-cycles,
            # a link failure) leaves it open
            agent.flush_source()
            agent.finish(close_open_cycle=True)
            runner.report()
        if args.json:
            print(to_json({**agent.run_statistics(), "prognosis": prognosis_summary(last.last),
                           "stopped": stop_text(runner, args), "health": runner.health().to_dict()}), flush=True)
        if runner.link_failure:
            print(f"edge-monitor run: stopped because the CAN link failed: {runner.link_failure}", file=sys.stderr)
            return EXIT_FAILURE
        if verbosity(args) >= 0:
            print(final_line(runner, args), file=sys.stderr, flush=True)
    problems = output_failures(app.agent, store)       # after the exit stack: the final state save included
    for problem in problems:
        print(f"edge-monitor run: {problem}", file=sys.stderr)
    return EXIT_FAILURE if problems else 0
