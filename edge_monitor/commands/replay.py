"""``edge-monitor replay FILE``: run the agent over a recorded log, deterministically, as fast as possible.

A damaged log is read as far as it goes: bad lines of a text log are skipped and counted, a file cut
short is reported and its last cycle is left open (not published; a later replay of the complete log
publishes it). Both are in the summary and in ``--json`` under ``"log"``.

Progress: a bar on stderr when it is a terminal (off with ``-q``), else an INFO line every 5 s (``-v``).
Exit code 1 when the log cannot be found or read (or is not a regular file: a FIFO, a device), the
``--jsonl`` file cannot be opened, or records or the state could not be written (a full disk:
``sink_errors``, ``state_save_errors``; the statistics are printed first)."""

from __future__ import annotations

import argparse
import logging
import os
import sys
import time
from contextlib import ExitStack
from pathlib import Path
from typing import Iterator

from edge_monitor.app import Outputs, build_app
from edge_monitor.commands.common import (
    add_config_arguments,
    load_agent_config,
    open_mapped_source,
    open_state_store,
    output_failures,
    print_json,
    setup_failure,
    summary_table,
)
from edge_monitor.pipeline.agent import Agent
from edge_monitor.pipeline.frame_source import FrameArrays
from edge_monitor.pipeline.log_source import LogReadError, LogReport, log_blocks_with_position
from edge_monitor.pipeline.trace_source import TraceError, TraceUnreadable, is_trace_file, replay_trace
from edge_monitor.sinks.base import LastSymptomSink
from edge_monitor.sinks.jsonl import JsonlOpenError
from protocol.console import EXIT_FAILURE, EXIT_USAGE, progress_bar, verbosity

log = logging.getLogger(__name__)


def add_parser(subparsers: argparse._SubParsersAction) -> None:
    p = subparsers.add_parser("replay", help="run the agent over a python-can log (.blf/.log/.asc) or a trace "
                                             "table (.csv/.parquet, with --mapping)",
                              description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("file", help="python-can log file, or a CSV/Parquet trace table (needs --mapping)")
    add_config_arguments(p)
    p.add_argument("--json", action="store_true",
                   help="print the run summary as JSON instead of the table (schema: edge-monitor schema summary)")
    p.add_argument("--rerun", default="off", metavar="SPEC",
                   help="draw the run in Rerun: off (default), save:PATH (a recording, compacted when closed), spawn "
                        "(a viewer; without a display: save:<log name>.rrd) or connect:URL")
    p.add_argument("--no-close", action="store_true",
                   help="leave the last cycle open at end of file (as if the stream continued)")
    p.set_defaults(func=run)


def _blocks(path: str, block_size: int, report: LogReport) -> Iterator[tuple[FrameArrays, int]]:
    """Frame blocks of the log with the bytes read so far; an I/O error becomes LogReadError naming the file."""
    try:
        yield from log_blocks_with_position(path, block_size, report)
    except OSError as exc:
        if isinstance(exc, FileNotFoundError):
            raise
        raise LogReadError(f"cannot read {path}: {exc}") from exc


def replay(agent: Agent, path: str, block_size: int, progress_s: float = 5.0, bar: bool = False) -> LogReport:
    """Feed the log to the agent; progress as a bar over the file's bytes (``bar`` and stderr a
    terminal), else an INFO line every ``progress_s``. Returns what reading the file found."""
    report = LogReport()
    size = os.path.getsize(path) if os.path.isfile(path) else None
    with progress_bar(size, f"replay {os.path.basename(path)}", enabled=bar, unit="B", unit_scale=True,
                      unit_divisor=1024) as progress:
        next_report = time.monotonic() + progress_s
        for (ids, data, dlc, ts), position in _blocks(path, block_size, report):
            agent.update(ids, data, dlc, ts)
            progress.update(max(position - progress.n, 0))
            if progress.disable and time.monotonic() >= next_report:
                log.info("replay: %d frames, %d cycles, %d symptoms", agent.frames_total, agent.stats.cycles,
                         agent.stats.symptoms)
                next_report = time.monotonic() + progress_s
    return report


def run(args: argparse.Namespace) -> int:
    cfg, source = open_mapped_source(load_agent_config(args), args.mapping)
    last = LastSymptomSink()
    store = open_state_store(cfg)
    with ExitStack() as stack:
        try:
            agent = build_app(cfg, Outputs(jsonl=cfg.jsonl, rerun=args.rerun,
                                           rerun_fallback=Path(args.file).with_suffix(".rrd").name),
                              stack, store, source=source).agent
        except (ValueError, JsonlOpenError) as exc:   # a bad --rerun, an unwritable recording or JSONL file
            return setup_failure("replay", exc)
        agent.sinks.append(last)
        try:
            if is_trace_file(args.file):
                report = replay_trace(agent, args.file, args.mapping)
            else:
                report = replay(agent, args.file, cfg.block_size, bar=verbosity(args) >= 0)
        except (FileNotFoundError, LogReadError, TraceUnreadable) as exc:
            print(f"edge-monitor replay: {exc}", file=sys.stderr)
            return EXIT_FAILURE
        except TraceError as exc:
            print(f"edge-monitor replay: {exc}", file=sys.stderr)
            return EXIT_USAGE
        if not args.no_close:
            agent.flush_source()
        agent.finish(close_open_cycle=not args.no_close and report.truncated is None)
        stats = {**agent.run_statistics(), "log": report.to_dict()}
    if args.json:
        print_json(stats)
    elif verbosity(args) >= 0:              # -q: no summary
        print(summary_table(last.last, stats, cfg.decision))
        print(f"frames {stats['frames_total']} (ok {stats['frames_ok']}, crc errors {stats['crc_errors']}, "
              f"lost {stats['counter_lost']}), cycles {stats['cycles']}, symptoms {stats['symptoms']}, "
              f"{stats['frames_per_second']:.0f} frames/s")
        if report.skipped or report.truncated:
            print(f"log: {report.skipped} unreadable record(s) skipped"
                  + (f"; truncated ({report.truncated}): its last cycle was not published" if report.truncated
                     else ""))
    problems = output_failures(agent, store)      # after the exit stack: the final state save included
    for problem in problems:
        print(f"edge-monitor replay: {problem}", file=sys.stderr)
    return EXIT_FAILURE if problems else 0
