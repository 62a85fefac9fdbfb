"""``edge-monitor replay FILE``: run the agent over a recorded log, deterministically, as fast as possible.

A damaged log is read as far as it goes: bad lines of a text log are skipped and counted, a file cut
short is reported and its last cycle is left open (not published; a later replay of the complete log
publishes it). Both are in the summary and in ``--json`` under ``"log"``.

Progress: a bar on stderr when it is a terminal (off with ``-q``), else an INFO line every 5 s (``-v``).
``--jobs 2`` (the default ``auto`` for a CAN log over :data:`AUTO_SPLIT_BYTES` where there are two
cores and no state file is kept) reads and ingests the log in this process and monitors the joints in a second one
(:mod:`edge_monitor.monitor_process`): the same records, in about two thirds of the time.
Exit code 1 when the log cannot be found or read (or is not a regular file: a FIFO, a device; or no frame in
it is readable: "is it a CAN log?"), the ``--jsonl`` file cannot be opened, or records or the state could not
be written (a full disk: ``sink_errors``, ``state_save_errors``; the statistics are printed first), or when a
mapped input was read but no cycle was found (the reason and the check-mapping command to run are printed).
With ``--state-dir`` the replay notes its input's last frame time there (``replayed_input.json``); an input that
begins before the one replayed last ended (the same log again, an older one) gets a warning: its cycles would be
learned again as new ones, so replay it with a fresh ``--state-dir`` (a warning, not a refusal: an agent restarted
on its state keeps going whatever the controller's numbering does; logs timed from their start are not checked)."""

from __future__ import annotations

import argparse
import contextlib
import json
import logging
import os
import shlex
import sys
import tempfile
import time
from contextlib import ExitStack
from pathlib import Path
from typing import Any, Callable, Iterator

import numpy as np
from numpy.typing import NDArray

from edge_monitor.app import Outputs, build_app
from edge_monitor.commands.common import (
    add_config_arguments,
    load_agent_config,
    open_mapped_source,
    open_state_store,
    print_json,
    prognosis_summary,
    summary_table,
)
from edge_monitor.monitor_process import MonitorProcess, MonitorProcessError, MonitorResult
from edge_monitor.pipeline.agent import Agent
from edge_monitor.records import LATEST_WALL_TIME, utc_text
from edge_monitor.run_failures import output_failures, setup_failure
from edge_monitor.sinks.base import LastSymptomSink
from edge_monitor.sinks.jsonl import JsonlOpenError
from edge_monitor.sources.frame_source import FrameArrays
from edge_monitor.sources.ingest import Ingest
from edge_monitor.sources.log_source import LogReadError, LogReport, log_blocks_with_position
from edge_monitor.sources.trace_source import replay_trace
from edge_monitor.sources.trace_table import TraceError, TraceUnreadable, is_trace_file
from protocol.console import EXIT_FAILURE, EXIT_USAGE, LOG_FORMAT, progress_bar, verbosity
from protocol.files import read_regular

log = logging.getLogger(__name__)

#: ``--jobs auto`` splits a replay of a CAN log this large or larger [bytes]: below it, starting the
#: second process (≈ 2 s of imports) costs more than it saves.
AUTO_SPLIT_BYTES = 64 * 2 ** 20
#: Where a replay notes the last frame time of its input in ``--state-dir``.
REPLAYED_FILE = "replayed_input.json"
#: Frame times from this on are times since 1970 (2001-09-09) [s]; earlier ones count from the recording's start.
ABSOLUTE_TIME_S = 1e9


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
    p.add_argument("--jobs", default="auto", choices=("auto", "1", "2"),
                   help="2: read and ingest the log in this process, monitor the joints in a second one (the "
                        "same records, faster on two cores); auto (default): 2 for a CAN log of 64 MiB or more "
                        "on two or more cores without a state file, else 1")
    p.set_defaults(func=run)


def _blocks(path: str, block_size: int, report: LogReport) -> Iterator[tuple[FrameArrays, int]]:
    """Frame blocks of the log with the bytes read so far; an I/O error becomes LogReadError naming the file."""
    try:
        yield from log_blocks_with_position(path, block_size, report)
    except OSError as exc:
        if isinstance(exc, FileNotFoundError):
            raise
        raise LogReadError(f"cannot read {path}: {exc}") from exc


def replay(path: str, block_size: int, feed: Callable[[NDArray, NDArray, NDArray, NDArray], Any],
           status: Callable[[], str], progress_s: float = 5.0, bar: bool = False) -> LogReport:
    """Feed the log's frame blocks to ``feed`` (the agent, or the ingest of a split replay); progress as
    a bar over the file's bytes (``bar`` and stderr a terminal), else an INFO line ``status()`` every
    ``progress_s``. Returns what reading the file found."""
    report = LogReport()
    size = os.path.getsize(path) if os.path.isfile(path) else None
    with progress_bar(size, f"replay {os.path.basename(path)}", enabled=bar, unit="B", unit_scale=True,
                      unit_divisor=1024) as progress:
        next_report = time.monotonic() + progress_s
        for (ids, data, dlc, ts), position in _blocks(path, block_size, report):
            feed(ids, data, dlc, ts)
            progress.update(max(position - progress.n, 0))
            if progress.disable and time.monotonic() >= next_report:
                log.info("replay: %s", status())
                next_report = time.monotonic() + progress_s
    return report


class InputTimes:
    """First and last frame (or row) time of the input [s since 1970], checked against the last input replayed
    onto the same ``--state-dir`` (:data:`REPLAYED_FILE` there): an input that begins before it ended (the same
    log again, an older one) would be learned again as new cycles, so a warning says so once."""

    def __init__(self, state_dir: Path | None, file: str) -> None:
        self.first: float | None = None
        self.last: float | None = None
        self.file = file
        self.path = None if state_dir is None else state_dir / REPLAYED_FILE
        self.before = self._read()

    def _read(self) -> dict[str, Any]:
        try:
            saved = json.loads(read_regular(self.path, 1 << 16)) if self.path and os.path.lexists(self.path) else {}
        except (OSError, ValueError, RecursionError):       # NotARegularFile is a ValueError
            return {}
        last = saved.get("last_time") if isinstance(saved, dict) else None
        if isinstance(last, bool) or not isinstance(last, (int, float)) \
                or not ABSOLUTE_TIME_S <= last < LATEST_WALL_TIME:
            return {}                 # not written by us (or edited by hand): nothing to compare with
        return {"input": str(saved.get("input", "the input"))[:200], "last_time": float(last)}

    def see(self, times: NDArray) -> None:
        if not len(times):
            return
        if self.first is None:
            self.first = float(times[0])
            if self.first >= ABSOLUTE_TIME_S and self.before and self.first < float(self.before["last_time"]):
                log.warning("%s begins at %s, before the end (%s) of %s replayed onto this --state-dir: its cycles "
                            "are learned again as new ones; replay it with a fresh --state-dir", self.file,
                            utc_text(self.first), utc_text(float(self.before["last_time"])),
                            self.before.get("input", "the input"))
        self.last = max(float(times[-1]), self.last if self.last is not None else -np.inf)

    def save(self) -> None:
        """Remember this input's end for the next replay onto the state directory (absolute times only)."""
        if self.path is None or self.last is None or self.last < ABSOLUTE_TIME_S:
            return
        partial = None
        try:            # a new file of our own (not a FIFO or a symlink someone left at a fixed name: no hang)
            fd, partial = tempfile.mkstemp(prefix=f".{self.path.name}.", suffix=".partial", dir=self.path.parent)
            with os.fdopen(fd, "w", encoding="utf-8") as fh:
                fh.write(json.dumps({"input": os.path.basename(self.file), "last_time": self.last}))
            os.replace(partial, self.path)
            partial = None
        except OSError as exc:
            log.debug("cannot write %s: %s", self.path, exc)
        finally:
            if partial is not None:
                with contextlib.suppress(OSError):
                    os.unlink(partial)


def _agent_status(agent: Agent) -> str:
    return f"{agent.frames_total} frames, {agent.stats.cycles} cycles, {agent.stats.symptoms} symptoms"


def _outputs(args: argparse.Namespace, cfg: Any) -> Outputs:
    """The replay's outputs: the configured JSONL file and ``--rerun`` (a recording named after the log
    where no viewer can be spawned)."""
    return Outputs(jsonl=cfg.jsonl, rerun=args.rerun, rerun_fallback=Path(args.file).with_suffix(".rrd").name)


def _jobs(args: argparse.Namespace, store: Any) -> int:
    """How many processes the replay uses (``--jobs``; auto: 2 for a CAN log of at least
    :data:`AUTO_SPLIT_BYTES` without a state file on two or more cores)."""
    if args.jobs != "auto":
        return int(args.jobs)
    try:
        large = os.path.getsize(args.file) >= AUTO_SPLIT_BYTES
    except OSError:
        large = False                          # a missing file is reported by the replay itself
    return 2 if large and (os.cpu_count() or 1) >= 2 and store is None and not is_trace_file(args.file) else 1


def _run_split(args: argparse.Namespace, cfg: Any, source: Any) -> int:
    """``replay --jobs 2``: ingest here, monitor in a second process (module docstring)."""
    started = time.perf_counter()
    source = source if source is not None else Ingest.for_config(cfg)
    monitor = MonitorProcess(cfg, _outputs(args, cfg), logging.getLogger().level, LOG_FORMAT)
    try:
        if monitor.setup is not None:
            return int(monitor.setup.setup_exit or EXIT_FAILURE)
        try:
            def feed(ids: NDArray, data: NDArray, dlc: NDArray, ts: NDArray) -> None:
                block = source.update(ids, data, dlc, ts)
                if block.runs:
                    monitor.update(block)

            report = replay(args.file, cfg.block_size, feed, bar=verbosity(args) >= 0,
                            status=lambda: f"{source.c.frames_total} frames ingested (the joints monitored in "
                                           "a second process)")
        except (FileNotFoundError, LogReadError) as exc:
            print(f"edge-monitor replay: {exc}", file=sys.stderr)
            return EXIT_FAILURE
        flush = getattr(source, "flush", None)
        flushed = flush() if flush is not None and not args.no_close else None
        result = monitor.finish(not args.no_close and report.truncated is None, source.counters(),
                                dict(source.e2e.stats), flushed)
    except MonitorProcessError as exc:
        print(f"edge-monitor replay: {exc}", file=sys.stderr)
        return EXIT_FAILURE
    finally:
        monitor.close()
    wall = time.perf_counter() - started
    stats = {**result.statistics, "wall_s": wall, "log": report.to_dict()}
    stats["frames_per_second"] = stats["frames_total"] / wall if wall > 0 else 0.0
    return _report(args, cfg, stats, report, result)


def _out_of_sequence(stats: dict[str, Any]) -> str:
    """", out of sequence N (…)" when frames came with an alive counter that jumped beyond ``max_delta``: lost
    frames whose number the counter cannot tell (a recording or a link that dropped runs of frames)."""
    n = stats.get("details", {}).get("wrong_sequence", 0)
    return f", out of sequence {n}: frames lost in runs the alive counter cannot count" if n else ""


def _report(args: argparse.Namespace, cfg: Any, stats: dict[str, Any], report: LogReport,
            result: MonitorResult, raised: dict[int, dict] | None = None) -> int:
    """The summary (table or ``--json``) and the exit code (1 when an output or the state failed)."""
    if args.json:
        print_json({**stats, "prognosis": prognosis_summary(result.last)})
    elif verbosity(args) >= 0:              # -q: no summary
        print(summary_table(result.last, stats, cfg.decision, raised))
        table = is_trace_file(args.file)
        print(_counts(stats, report) if table else
              f"frames {stats['frames_total']} (ok {stats['frames_ok']}, crc errors {stats['crc_errors']}, "
              f"lost {stats['counter_lost']}{_out_of_sequence(stats)}), cycles {stats['cycles']}, "
              f"symptoms {stats['symptoms']}, "
              f"{stats['frames_per_second']:.0f} frames/s")
        if report.skipped or report.truncated:
            print(f"log: {report.skipped} unreadable {'row' if table else 'record'}(s) skipped"
                  + (f"; truncated ({report.truncated}): its last cycle was not published" if report.truncated
                     else ""))
    notes, nothing = input_notes(args.file, stats, report, getattr(args, "mapping", None))
    for note in notes:
        log.warning("%s", note)
    for problem in result.failures + ([nothing] if nothing else []):
        print(f"edge-monitor replay: {problem}", file=sys.stderr)
    return EXIT_FAILURE if result.failures or nothing else 0


def _counts(stats: dict[str, Any], report: LogReport) -> str:
    """The counts line of a trace table's replay: the samples read (``log.frames``: one per joint and row; a
    table has no CAN frames to count), cycles, symptoms, samples per second."""
    wall = float(stats.get("wall_s") or 0.0)
    rate = report.frames / wall if wall > 0 else 0.0
    return (f"samples {report.frames}, cycles {stats['cycles']}, symptoms {stats['symptoms']}, "
            f"{rate:.0f} samples/s")


def input_notes(file: str, stats: dict[str, Any], report: Any,
                mapping: str | None = None) -> tuple[list[str], str | None]:
    """What the input lost (lines for the log: samples dropped and frames not used, by reason), and why
    nothing was monitored when a log held nothing the agent could use or a mapped input gave no cycle
    (None when something was)."""
    finding = stats.get("details", {}).get("cycle_finding") or {}
    dropped = {k: v for k, v in (stats.get("details", {}).get("samples_dropped") or {}).items() if v}
    if not_enabled := stats.get("details", {}).get("not_enabled"):       # CiA 402: the statusword gate
        dropped["drive not in operation enabled (statusword 6041h)"] = not_enabled
    unused = {k: stats[k] for k in ("unknown_id", "malformed") if stats.get(k)}
    notes = [f"{file}: {what}: " + ", ".join(f"{k.replace('_', ' ')} {v}" for k, v in counts.items())
             for what, counts in (("samples dropped", dropped), ("frames not used", unused)) if counts]
    nothing = None
    if stats["cycles"] == 0 and stats["frames_total"] and stats.get("unknown_id") == stats["frames_total"]:
        nothing = (f"no frame of {file} has an id this agent decodes ({stats['frames_total']} frames): a foreign "
                   "controller's log? replay it with --mapping (docs/CONNECTING.md)")
    elif stats["cycles"] == 0 and not stats["frames_total"] and _nothing_read(report):
        why = f"{report.skipped} unreadable record(s)" if report.skipped else "no CAN frame found"
        ended = f"; it ends early: {report.truncated}" if report.truncated else ""
        nothing = f"nothing in {file} is readable ({why}{ended}): is it a CAN log?"
    elif stats["cycles"] == 0 and finding and (stats["frames_total"] or getattr(report, "frames", 0)):
        nothing = no_cycle_note(file, finding, mapping, getattr(report, "truncated", None))
        if nothing and not_enabled:
            nothing += (f"; {not_enabled} samples were dropped while the drive's statusword 6041h did not read "
                        "operation enabled (a drive switched off, in fault or not yet enabled)")
    return notes, nothing


def _nothing_read(report: Any) -> bool:
    """The input gave nothing: records were all unreadable, or no frame was found in it at all."""
    return isinstance(report, LogReport) and bool(report.skipped or not report.frames)


def no_cycle_note(file: str, finding: dict[str, Any], mapping: str | None, truncated: str | None) -> str | None:
    """Why a mapped input that was read found no cycle (the cycle finding's counters), pointing to
    check-mapping; None when the log was cut short (its only cycle is left open, not lost)."""
    if truncated:
        return None
    why = ", ".join(f"{k.replace('_', ' ')} {v}" for k, v in finding.items()
                    if k in ("before_first_cycle", "bad_marks", "cycle_jumps", "plateaus_ignored") and v)
    check = (f"edge-monitor check-mapping {shlex.quote(file)}"
             + (f" --mapping {shlex.quote(mapping)}" if mapping else ""))
    return (f"no cycle found in {file} ({finding.get('method', 'cycle finding')}"
            + (f": {why.replace('before first cycle', 'samples before the first cycle')}" if why else "")
            + f"): does the mapping's [cycles] fit the input? run {check} (docs/CONNECTING.md)")


def run(args: argparse.Namespace) -> int:
    cfg, source = open_mapped_source(load_agent_config(args), args.mapping, table=is_trace_file(args.file))
    last = LastSymptomSink()
    store = open_state_store(cfg)
    if _jobs(args, store) == 2:
        if store is not None:
            print("edge-monitor replay: --jobs 2 keeps no state file; use --jobs 1 with a state file", file=sys.stderr)
            return EXIT_USAGE
        if is_trace_file(args.file):
            print("edge-monitor replay: --jobs 2 replays CAN logs; a trace table replays with --jobs 1",
                  file=sys.stderr)
            return EXIT_USAGE
        return _run_split(args, cfg, source)
    with ExitStack() as stack:
        try:
            agent = build_app(cfg, _outputs(args, cfg), stack, store, source=source).agent
        except (ValueError, JsonlOpenError) as exc:   # a bad --rerun, an unwritable recording or JSONL file
            return setup_failure("replay", exc)
        agent.sinks.append(last)
        times = InputTimes(None if store is None else Path(store.dir), args.file)

        def feed(ids: NDArray, data: NDArray, dlc: NDArray, ts: NDArray) -> Any:
            times.see(ts)
            return agent.update(ids, data, dlc, ts)
        try:
            if is_trace_file(args.file):
                report = replay_trace(agent, args.file, args.mapping, times.see)
            else:
                report = replay(args.file, cfg.block_size, feed, lambda: _agent_status(agent),
                                bar=verbosity(args) >= 0)
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
        times.save()
    # output failures after the exit stack: the final state save included
    return _report(args, cfg, stats, report, MonitorResult(stats, last.last, output_failures(agent, store)),
                   last.raised)
