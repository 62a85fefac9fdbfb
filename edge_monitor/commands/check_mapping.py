"""``edge-monitor check-mapping``: commission the agent on a new robot — what each joint's signals decode to.

Reads a capture (a python-can log, or a trace table for a ``trace`` mapping) or listens on a live bus
(listen-only: nothing is sent) for ``--seconds``, decodes it as the agent would and prints per joint:
the signals used, samples, rate, the range of speed [rad/s], torque [fraction of T_ref], load and motor
temperature, what is missing (and what the agent falls back to), the steady speeds found, the test
cycle's levels in its order without the production motion's speeds (what ``[cycles] speeds`` should say:
a mapping may leave it out for this check) and the cycles found. Without ``--mapping``: our own frames.

Exit codes: 0 the mapping decodes; 2 a mapping that does not load or names a missing message, signal or
object, a unit that does not convert, a joint with no frames, values no robot has (beyond any robot's,
or never above a moving one's: a wrong unit, scale or reference torque), no cycle found, cycle marks that
are no counter, frames cut short or failing E2E, or ``[cycles] speeds`` missing; 1 the capture or link
cannot be read.
"""

from __future__ import annotations

import argparse
import math
import sys
import time
from typing import Any, Iterator

import numpy as np

from edge_monitor.commands.common import load_agent_config, print_json
from edge_monitor.sources.frame_source import FrameArrays
from edge_monitor.sources.ingest import Ingest
from edge_monitor.sources.log_source import LogReadError, log_blocks
from edge_monitor.sources.samples import DecodedSamples, IngestBlock, JointColumns, StatusColumns
from edge_monitor.sources.signal_check import SignalCheck
from protocol.console import EXIT_FAILURE, EXIT_USAGE, UsageError, add_can_arguments, can_options

FALLBACK = {"temperature": "the site temperature range ([wear] temperature_min … temperature_max) for the wear, the "
                           "lubricant temperature read from the friction for the detectors' stages, spans and slack",
            "load": "the load the test cycle's plateaus measure (the configured prior [wear] default_load_mean ± "
                    "default_load_std only for a cycle without plateaus in both directions)"}


def add_parser(subparsers: argparse._SubParsersAction) -> None:
    p = subparsers.add_parser("check-mapping", help="show what a mapping decodes a capture or live bus to "
                                                    "(commissioning)", description=__doc__,
                              formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("capture", nargs="?", help="log file (.blf/.log/.asc) or trace table (.csv/.parquet); "
                                              "omit to listen on --link")
    p.add_argument("--mapping", metavar="MAPPING.toml", help="mapping file (default: our own frames)")
    p.add_argument("--config", metavar="FILE", help="agent TOML config (rate_hz, [segmentation])")
    p.add_argument("--seconds", type=float, default=120.0,
                   help="how much of the capture / how long to listen [s] (default 120: a few test cycles)")
    p.add_argument("--json", action="store_true", help="print the report as JSON")
    add_can_arguments(p, "listen on this link (listen-only), e.g. slcan:/dev/ttyACM0 or socketcan:can0")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    if not (math.isfinite(args.seconds) and args.seconds > 0):
        raise UsageError(f"--seconds {args.seconds}: give how much to read, > 0 s (e.g. 120: a few test cycles)")
    cfg = load_agent_config(args)
    try:
        check, decode = _prepare(cfg, args.mapping)
    except ValueError as exc:
        print(f"edge-monitor check-mapping: {exc}", file=sys.stderr)
        return EXIT_USAGE
    except OSError as exc:          # a mapping, DBC or EDS file that cannot be read
        print(f"edge-monitor check-mapping: {exc}", file=sys.stderr)
        return EXIT_FAILURE
    try:
        for decoded in _decoded(args, decode, check.rate_hz):
            check.update(decoded)
    except (FileNotFoundError, LogReadError, OSError) as exc:
        print(f"edge-monitor check-mapping: cannot read the capture: {exc}", file=sys.stderr)
        return EXIT_FAILURE
    except ValueError as exc:       # a trace table that does not fit its mapping
        print(f"edge-monitor check-mapping: {exc}", file=sys.stderr)
        return EXIT_USAGE
    report = check.report()
    print_json(report) if args.json else print(_text(report))
    return EXIT_USAGE if report["problems"] else 0


def _prepare(cfg: Any, mapping_path: str | None) -> tuple[SignalCheck, Any]:
    """The check and a decoder ``(ids, data, dlc, ts) -> DecodedSamples`` (or the mapping, for tables)."""
    if mapping_path is None:
        ingest = Ingest(rate_hz=cfg.rate_hz, joints=cfg.joints)
        native = SignalCheck([], cfg.rate_hz, None, cfg.segmentation, frames=ingest.c)
        native.cycles_seen = set()
        return native, lambda *block: _native(ingest.update(*block), cfg.rate_hz, native.cycles_seen)
    from edge_monitor.pipeline.agent_config import config_for
    from edge_monitor.sources.foreign_source import decoder_for, open_source
    from protocol.signal_mapping import load_mapping
    mapping = load_mapping(mapping_path, commissioning=True)
    speeds_missing = mapping.cycles.source != "controller" and not mapping.cycles.speeds
    cfg = config_for(cfg, mapping)
    decoder = decoder_for(mapping)
    stream = None if speeds_missing else open_source(mapping, cfg).stream
    check = SignalCheck(sorted(mapping.joints), cfg.rate_hz, stream, cfg.segmentation,
                        decoder.describe() if decoder is not None else
                        {j: {q: r.describe() for q in ("speed", "torque", "load", "temperature")
                             if (r := getattr(jm, q)) is not None} for j, jm in mapping.joints.items()},
                        frames=decoder.c if decoder is not None else None,
                        reference_joint=mapping.cycles.reference_joint)
    check.speeds_missing = speeds_missing
    return check, (decoder.decode if decoder is not None else mapping)


def _native(block: IngestBlock, rate_hz: float, cycles: set[int] | None) -> DecodedSamples:
    """Our frames after ingest, as decoded columns (status entries spread over their run's time); the
    cycles of the runs go into ``cycles``."""
    out = DecodedSamples()
    for run in block.runs:
        if cycles is not None and run.cycle is not None and len(cycles) < 100_000:
            cycles.add(run.cycle)
        for j, s in run.samples.items():
            out.joints[j] = JointColumns(s.tick / rate_hz, s.speed, s.torque)
        for j, st in run.joint_status.items():
            ticks = next((s.tick for s in run.samples.values() if s.tick.size), np.zeros(1, np.int64))
            t = np.linspace(ticks[0], ticks[-1], st.load_estimate.size) / rate_hz
            out.status[j] = StatusColumns(t, st.load_estimate, st.motor_temperature)
    return out


def _decoded(args: argparse.Namespace, decode: Any, rate_hz: float) -> Iterator[DecodedSamples]:
    if not callable(decode):                  # a trace mapping: read the table
        from edge_monitor.sources.trace_source import decoded_batches
        if not args.capture:
            raise ValueError("a trace mapping checks a table: give the CSV/Parquet file")
        for decoded in decoded_batches(args.capture, decode, rate_hz=rate_hz):   # the mapping's rate
            yield decoded
        return
    for ids, data, dlc, ts in _frames(args):
        yield decode(ids, data, dlc, ts)


def _frames(args: argparse.Namespace) -> Iterator[FrameArrays]:
    """The first ``--seconds`` of the capture, or of the live bus (receive only)."""
    if args.capture:
        start = None
        for block in log_blocks(args.capture, 4096):
            start = float(block[3][0]) if start is None and block[3].size else start
            keep = block[3] <= (start or 0.0) + args.seconds
            yield tuple(a[keep] for a in block)
            if not keep.all():
                return
        return
    from protocol.frames import messages_to_arrays
    from protocol.links import open_bus
    bus = open_bus(args.link, **can_options(args))
    try:
        end = time.monotonic() + args.seconds
        batch = []
        while time.monotonic() < end:
            message = bus.recv(timeout=0.1)          # receive only: the check never sends
            if message is not None:
                batch.append(message)
            if len(batch) >= 4096 or (batch and message is None):
                yield messages_to_arrays(batch)
                batch = []
        if batch:
            yield messages_to_arrays(batch)
    finally:
        bus.shutdown()


def _fmt(r: dict[str, Any] | None, unit: str) -> str:
    if r is None:
        return "missing"
    rate = f", {r['rate_hz']:.0f} Hz" if r.get("rate_hz") else ""
    return f"{r['min']:.4g} … {r['max']:.4g} {unit} ({r['samples']} values{rate})"


def _text(report: dict[str, Any]) -> str:
    lines = []
    for j, jr in report["joints"].items():
        lines.append(f"joint {j}: " + ", ".join(f"{k} = {v}" for k, v in jr["signals"].items()))
        for q, unit in (("speed", "rad/s"), ("torque", "of T_ref"), ("load", "of T_ref"), ("temperature", "°C")):
            text = _fmt(jr[q], unit)
            if jr[q] is None and q in FALLBACK:
                text += f" → the agent uses {FALLBACK[q]}"
            lines.append(f"  {q:<12} {text}")
        lines.append(f"  steady speeds found [rad/s]: {jr['steady_speeds'] or 'none'}")
    levels = report["test_cycle_levels"]
    if levels["speeds"]:
        lines.append(f"test cycle levels in its order [rad/s]: speeds = [{', '.join(map(str, levels['speeds']))}]"
                     + (f" (production motion left out: {levels['production']})" if levels["production"] else ""))
    if "cycles" in report:
        c = report["cycles"]
        lines.append(f"cycles from the {c['method']}: {c['cycles_found']} found"
                     + (f", {c['plateaus_ignored']} plateaus outside the test cycle ignored"
                        if "plateaus_ignored" in c else "")
                     + f", {c['before_first_cycle']} samples before the first cycle")
    lines += [f"PROBLEM: {p}" for p in report["problems"]] or ["mapping OK"]
    return "\n".join(lines)
