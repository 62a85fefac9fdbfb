"""``edge-monitor export-trace LOG --out TRACE.csv``: a recording as a trace table, with the mapping that
replays it (``edge-monitor replay TRACE.csv --mapping TRACE.toml``). Decoded as the agent decodes it:
our frames, or another controller's with ``--mapping``. The table and its mapping are new files: an
existing one (or the recording, or the mapping read) is never written over without ``--force``, and
never the input. The table gets its name only when complete: an export cut short leaves none. Exit
codes: 2 a bad option or output path, 1 a recording that cannot be read or an output that cannot be
written."""

from __future__ import annotations

import argparse
import logging
import os
import shlex
import sys
import tomllib
from pathlib import Path
from typing import Any

from edge_monitor.commands.common import load_agent_config, open_mapped_source
from edge_monitor.commands.output_paths import check_output, name_too_long, same_file, short_path
from edge_monitor.sources.ingest import Ingest
from edge_monitor.sources.log_source import LogReadError, LogReport, log_blocks_with_position
from edge_monitor.sources.samples import IngestBlock
from edge_monitor.sources.trace_export import TraceWriter
from edge_monitor.sources.trace_table import TRACE_SUFFIXES, is_trace_file
from protocol.console import EXIT_FAILURE, UsageError, verbosity
from protocol.signal_mapping import MappingError, mapping_from_dict

log = logging.getLogger(__name__)


def add_parser(subparsers: argparse._SubParsersAction) -> None:
    p = subparsers.add_parser("export-trace", help="export a recording as a CSV/Parquet trace table",
                              description=__doc__)
    p.add_argument("file", help="python-can log file")
    p.add_argument("--out", required=True, metavar="TRACE.csv",
                   help="table to write (.csv or .parquet); its mapping goes beside it as TRACE.toml")
    p.add_argument("--mapping", metavar="MAPPING.toml", help="the recording's controller is not ours")
    p.add_argument("--config", metavar="FILE", help="agent TOML config (rate_hz)")
    p.add_argument("--separator", default=";", help="CSV separator: one character such as ; , or a tab (default ;)")
    p.add_argument("--time-unit", choices=("s", "ms"), default="s")
    p.add_argument("--force", action="store_true", help="replace an existing table and mapping")
    p.set_defaults(func=run)


def check_outputs(args: argparse.Namespace) -> Path:
    """The mapping's path beside ``--out``; UsageError for an output that would destroy an input, exists
    (without ``--force``), lies in a missing folder, is no table, or a separator its own mapping refuses."""
    out = Path(args.out)
    if out.suffix.lower() not in TRACE_SUFFIXES:
        raise UsageError(f"--out {out}: a trace table ends in {', '.join(TRACE_SUFFIXES)} (its mapping is written "
                         f"beside it as {out.with_suffix('.toml').name})")
    mapping = out.with_suffix(".toml")
    for path, what in ((out, "table"), (mapping, "mapping")):
        for given, name in ((args.file, "the recording"), (args.mapping, "--mapping"), (args.config, "--config")):
            if given and same_file(path, Path(given)):
                raise UsageError(f"--out {out}: its {what} {path} is {name}: choose another --out")
        check_output(path, f"--out ({what})", overwrite=args.force)
    probe = TraceWriter(out, [0], 500.0, args.separator, args.time_unit)    # its names and its mapping's text
    partial = max((probe.partial, probe.mapping_partial), key=lambda p: len(os.fsencode(p.name)))
    if (too_long := name_too_long(partial)) is not None:
        raise UsageError(f"--out {short_path(out)}: its name is too long: the table is written first under the "
                         f"hidden name {short_path(Path(partial.name))} of {too_long[0]} bytes, its file system takes "
                         f"{too_long[1]}: choose a name {too_long[0] - too_long[1]} bytes shorter")
    try:
        mapping_from_dict(tomllib.loads(probe.mapping_text()))
    except (MappingError, tomllib.TOMLDecodeError) as exc:
        raise UsageError(f"--separator {args.separator!r}: {str(exc).split(': ', 2)[-1]}") from None
    remove_stale_partials(probe)
    return mapping


def remove_stale_partials(probe: TraceWriter) -> None:
    """Delete the hidden files of ``--out``'s name an export killed before it finished left (none is being
    written: nobody holds their lock), with a warning that says how many."""
    removed = []
    for path in probe.stale_partials():
        try:
            path.unlink()
            removed.append(path.name)
        except FileNotFoundError:
            continue
        except OSError as exc:
            log.warning("cannot remove %s, left by an export that did not finish (%s): delete it by hand",
                        path, exc.strerror or exc)
    if removed:
        log.warning("removed %d hidden file(s) beside %s left by an export that did not finish (killed, or the "
                    "machine stopped): %s", len(removed), probe.path.name, ", ".join(removed[:4]))


def run(args: argparse.Namespace) -> int:
    if not Path(args.file).is_file():         # a recording that is not there: a runtime failure, before the outputs
        print(f"edge-monitor export-trace: {args.file}: no such file", file=sys.stderr)
        return EXIT_FAILURE
    if is_trace_file(args.file):
        raise UsageError(f"{args.file}: already a trace table; export-trace takes a CAN log (.blf, .asc, .log, ...): "
                         f"replay the table with `edge-monitor replay {args.file} --mapping MAPPING`")
    mapping = check_outputs(args)
    try:
        import pyarrow  # noqa: F401 — the table writer
    except ImportError:
        print("edge-monitor export-trace: writing trace tables needs pyarrow: pip install "
              "'joint-wear-monitor[traces]'", file=sys.stderr)
        return EXIT_FAILURE
    cfg, source = open_mapped_source(load_agent_config(args), args.mapping)
    source = source or Ingest(rate_hz=cfg.rate_hz, joints=cfg.joints)
    try:
        writer = _export(args, cfg.rate_hz, cfg.block_size, source)
        if writer is None:
            print(f"edge-monitor export-trace: no joint samples in {args.file}", file=sys.stderr)
            return EXIT_FAILURE
    except (FileNotFoundError, LogReadError) as exc:
        print(f"edge-monitor export-trace: {exc}", file=sys.stderr)
        return EXIT_FAILURE
    except OSError as exc:
        print(f"edge-monitor export-trace: writing {args.out} failed ({exc}): check that its folder is writable "
              "and has space", file=sys.stderr)
        return EXIT_FAILURE
    if verbosity(args) >= 0:                # -q: errors only
        print(f"edge-monitor export-trace: {writer.rows} rows to {args.out}; replay it with "
              f"`edge-monitor replay {shlex.quote(args.out)} --mapping {shlex.quote(str(mapping))}`", file=sys.stderr)
    return 0


def _export(args: argparse.Namespace, rate_hz: float, block_size: int, source: Any) -> TraceWriter | None:
    """Write the recording's joint samples to the table ``--out``; None if it has none. Whatever stops the
    export (a read error, a full disk, Ctrl-C, SIGTERM) leaves no half table under ``--out``."""
    blocks: list[IngestBlock] = []         # held until the first samples tell which joints there are
    writer: TraceWriter | None = None
    report = LogReport()
    try:
        for (ids, data, dlc, ts), _ in log_blocks_with_position(args.file, block_size, report):
            blocks.append(source.update(ids, data, dlc, ts))
            writer = writer or _writer(args, rate_hz, blocks)
            if writer is not None:
                for block in blocks:
                    writer.write(block)
                blocks = []
        if hasattr(source, "flush"):
            blocks.append(source.flush())
        writer = writer or _writer(args, rate_hz, blocks)
        if writer is not None:
            for block in blocks:
                writer.write(block)
            writer.close(drop_open=report.truncated is not None)
            if writer.dropped_rows:
                log.warning("%s is truncated: its last cycle (%d rows) is left out of %s, as a replay of the log "
                            "leaves it unpublished", args.file, writer.dropped_rows, args.out)
        return writer
    except BaseException:
        if writer is not None:
            writer.discard()
        raise


def _writer(args: argparse.Namespace, rate_hz: float, blocks: list[IngestBlock]) -> TraceWriter | None:
    joints = sorted({j for block in blocks for run in block.runs if run.cycle is not None for j in run.samples})
    return TraceWriter(args.out, joints, rate_hz, args.separator, args.time_unit) if joints else None
