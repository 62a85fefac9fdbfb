"""Pieces shared by the agent's subcommands: config loading with overrides, sinks, summaries."""

from __future__ import annotations

import argparse
import logging
import sys
from typing import TYPE_CHECKING, Any

from edge_monitor.records import to_json
from edge_monitor.sinks.zenoh_session import DEFAULT_ROUTER_PORT, MODES, ZenohOptions
from protocol.console import EXIT_FAILURE, EXIT_USAGE, UsageError

if TYPE_CHECKING:     # the agent's modules load only for the commands that run it: listen starts fast
    from edge_monitor.config import AgentConfig
    from edge_monitor.pipeline.decision_config import DecisionConfig
    from edge_monitor.pipeline.state_store import StateStore

log = logging.getLogger(__name__)


def add_config_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--config", metavar="FILE", help="agent TOML config (default: embedded defaults)")
    parser.add_argument("--robot", help="robot name used in symptom records and Zenoh keys")
    parser.add_argument("--jsonl", metavar="PATH", help="append per-cycle symptom records to this JSON Lines file")
    parser.add_argument("--jsonl-max-bytes", type=int, metavar="N",
                        help="rotate the JSONL file to PATH.1 before it passes N bytes (config jsonl_max_bytes, "
                             "default 64 MiB; 0: never, e.g. with logrotate)")
    parser.add_argument("--jsonl-keep", type=int, metavar="K",
                        help="rotated JSONL files kept, PATH.1 … PATH.K (config jsonl_keep; default 5)")
    parser.add_argument("--state-dir", metavar="DIR", help="persist learned models and detector state here")
    parser.add_argument("--pf", type=float, help="false-alarm probability per test (overrides decision.pf)")
    parser.add_argument("--mapping", metavar="MAPPING.toml",
                        help="the controller is not ours: a mapping file for its DBC, CiA 402 drives or trace "
                             "table (docs/CONNECTING.md; examples: edge-monitor deploy --list)")


def add_zenoh_arguments(parser: argparse.ArgumentParser) -> None:
    """``--zenoh-mode/--zenoh-listen/--zenoh-connect/--zenoh-config`` (multicast scouting is always off)."""
    group = parser.add_argument_group("zenoh", "Zenoh session (multicast scouting is always off)")
    group.add_argument("--zenoh-mode", choices=MODES, default=None,
                       help="peer (default), client (through a router) or router")
    group.add_argument("--zenoh-listen", action="append", default=[], metavar="ENDPOINT",
                       help="endpoint to listen on, e.g. tcp/127.0.0.1:7448 (repeatable; default: none)")
    group.add_argument("--zenoh-connect", action="append", default=[], metavar="ENDPOINT",
                       help=f"peer or router to connect to, e.g. tcp/127.0.0.1:{DEFAULT_ROUTER_PORT} (repeatable)")
    group.add_argument("--zenoh-config", default=None, metavar="FILE.json5",
                       help="Zenoh JSON5 config file; the flags above override it")


def add_tls_arguments(parser: argparse.ArgumentParser, who: str) -> None:
    """``--tls-ca/--tls-cert/--tls-key``: connect to the router over TLS as ``who`` (docs/SECURITY.md)."""
    tls = parser.add_argument_group("TLS", f"connect to the router over TLS (docs/SECURITY.md), as {who}")
    tls.add_argument("--tls-ca", metavar="PEM", help="CA certificate the router's certificate is checked against")
    tls.add_argument("--tls-cert", metavar="PEM", help=f"{who}'s certificate (mTLS identity)")
    tls.add_argument("--tls-key", metavar="PEM", help="its private key")


def zenoh_options_with_tls(args: argparse.Namespace) -> ZenohOptions:
    """:func:`zenoh_options` plus the ``--tls-*`` files; ZenohSetupError for a bad config file or a plain
    endpoint with TLS."""
    from dataclasses import replace

    from edge_monitor.sinks.zenoh_security import TlsFiles
    options = zenoh_options(args)
    files = [getattr(args, name, None) for name in ("tls_ca", "tls_cert", "tls_key")]
    if any(files):
        options = replace(options, tls=TlsFiles.from_paths(*files))
    options.to_config()
    return options


def add_subscriber_arguments(parser: argparse.ArgumentParser, counted: str) -> None:
    """``--no-history``, ``--duration S`` and ``--count N`` of a command that follows what agents publish."""
    parser.add_argument("--no-history", action="store_true",
                        help="only what is published from now on, not what the agents' publishers still cache")
    parser.add_argument("--duration", type=float, default=None, metavar="S", help="stop after S seconds")
    parser.add_argument("--count", type=int, default=None, metavar="N", help=f"stop after N {counted}")


def check_subscriber_arguments(args: argparse.Namespace) -> None:
    """UsageError (exit code 2) for a ``--count`` below 1 or a ``--duration`` not above 0."""
    if args.count is not None and args.count < 1:
        raise UsageError(f"--count {args.count}: must be ≥ 1")
    if args.duration is not None and not args.duration > 0:
        raise UsageError(f"--duration {args.duration}: must be > 0 s")


def zenoh_options(args: argparse.Namespace) -> ZenohOptions:
    """The session the ``--zenoh-*`` flags describe (peer mode unless a config file says otherwise)."""
    config_file = getattr(args, "zenoh_config", None)
    mode = getattr(args, "zenoh_mode", None)
    if mode is None and config_file is None:
        mode = "peer"
    return ZenohOptions(mode=mode, listen=list(getattr(args, "zenoh_listen", []) or []),
                        connect=list(getattr(args, "zenoh_connect", []) or []), config_file=config_file)


def load_agent_config(args: argparse.Namespace) -> AgentConfig:
    """Config file + command-line overrides; exits with a clear message on bad input."""
    from edge_monitor.config import ConfigError, load_config, with_overrides
    try:
        cfg = load_config(args.config)
        cfg = with_overrides(cfg, robot=getattr(args, "robot", None), jsonl=getattr(args, "jsonl", None),
                             state_dir=getattr(args, "state_dir", None),
                             jsonl_max_bytes=getattr(args, "jsonl_max_bytes", None),
                             jsonl_keep=getattr(args, "jsonl_keep", None))
        if getattr(args, "pf", None) is not None:
            import dataclasses
            cfg = with_overrides(cfg, decision=dataclasses.replace(cfg.decision, pf=args.pf))
        return cfg
    except ConfigError as exc:      # invalid input, like a bad option value: exit code 2
        print(f"edge-monitor: configuration error: {exc}", file=sys.stderr)
        raise SystemExit(EXIT_USAGE) from None


def open_state_store(cfg: AgentConfig) -> StateStore | None:
    """The state store of ``--state-dir``; exits with code 1 when it cannot be used (a runtime failure)."""
    from edge_monitor.errors import StateError
    from edge_monitor.pipeline.state_store import StateStore
    if not cfg.state_dir:
        return None
    try:
        store = StateStore(cfg.state_dir)
        store.claim()           # one agent per state directory
        return store
    except StateError as exc:
        print(f"edge-monitor: {exc}", file=sys.stderr)
        raise SystemExit(EXIT_FAILURE) from None


def print_json(obj: Any) -> None:
    sys.stdout.write(to_json(obj, indent=2, separators=(",", ": ")) + "\n")


def fmt(x: Any, spec: str = ".3g") -> str:
    return "–" if x is None else format(x, spec)


def wear_text(wear: dict[str, Any]) -> str:
    """"ϖ̂ ± σ" where wear is identifiable, else the one-sided bound "≤ upper_95" (near ϖ = 0 the data
    cannot tell low wear from none, and a ± would be meaningless)."""
    estimate, std, upper = wear.get("estimate"), wear.get("std"), wear.get("upper_95")
    if estimate is None:
        return "–"
    if wear.get("identifiable") is False and upper is not None:
        return f"≤ {upper:.0f} (95 %)"
    return f"{estimate:.1f} ± {fmt(std, '.1f')}"


def coverage_text(record: dict[str, Any]) -> str:
    """"lowest–highest" share [%] of the cycles a joint's detectors tested (its symptom's ``coverage``)."""
    shares = [c.get("share") for c in (record.get("coverage") or {}).values() if c.get("share") is not None]
    if not shares:
        return "–"
    low, high = round(100 * min(shares)), round(100 * max(shares))
    return f"{low}" if low == high else f"{low}–{high}"


def prognosis_text(prognosis: dict[str, Any] | None) -> str:
    """The prognosis in a table cell: "12 d (8–20)", "beyond 30 d", "no trend", "critical", "learning"."""
    if not prognosis:
        return "–"
    state, days = prognosis.get("state"), prognosis.get("days")
    if state == "critical":
        return "critical"
    if state == "learning":
        return "learning"
    if prognosis.get("beyond_horizon") or not days:
        return "no trend" if state == "no_trend" else f"beyond {prognosis.get('horizon_days', 0):g} d"
    cycles = prognosis.get("cycles") or {}
    if (days.get("median") or 0) < 1 and cycles:       # under a day: test cycles
        return f"{_days(cycles.get('median'))} cyc ({_days(cycles.get('p10'))}–{_days(cycles.get('p90'))})"
    return f"{_days(days.get('median'))} d ({_days(days.get('p10'))}–{_days(days.get('p90'))})"


def _days(value: Any) -> str:
    if value is None:
        return "?"
    return f"{value:.0f}" if value >= 10 else f"{value:.2g}"


def prognosis_summary(last_symptoms: dict[int, dict]) -> dict[str, dict[str, Any]]:
    """Each joint's last prognosis (the summaries' ``"prognosis"``, keyed by joint)."""
    return {str(j): r["prognosis"] for j, r in sorted(last_symptoms.items()) if r.get("prognosis")}


def summary_table(last_symptoms: dict[int, dict], stats: dict[str, Any], decision: DecisionConfig,
                  raised: dict[int, dict] | None = None) -> str:
    """Per joint: cycles, wear (estimate ± std, or its 95 % upper bound where not identifiable), the
    estimated lubricant temperature, the detectors' stage (warm-up or steady, docs/DETECTION.md), alarms
    (quantity@cycle), the false-alarm setting, the smallest estimated miss probability over the
    joint's detectors, and the prognosis: days until the critical wear with the 10–90 % band; below, for
    each joint with a fault in ``raised`` (its last "raised" alarm record), the forecast the alarm carried; and
    the share of the cycles the joint's detectors tested since they first learned (coverage, lowest – highest
    over its detectors, docs/DETECTION.md)."""
    held = decision.warm_up_hold
    warm_up = ({"boundary": "for drifts up to the allowance during the warm-up",
                "nominal": "at the learned nominal during the warm-up"}.get(
                   decision.calibrate_at, "during the warm-up for the drift healthy joints show beyond their "
                                          "temperature slack")
               + (f" (its {', '.join(held)} detectors holding while the joint is outside the temperatures "
                  f"they learned at)" if held else ""))
    arl0 = stats.get("details", {}).get("arl0_cycles", decision.arl0)      # as the agent derived it last
    setting = (f"Pf {decision.pf:.2g} per test (expert setting)" if decision.pf is not None
               else f"mean run length to a false alarm {arl0:.3g} cycles per detector once steady, {warm_up}")
    lines = [f"{'joint':>5} {'cycles':>6} {'wear':>16} {'temp °C':>8} {'stage':>8} {'tested %':>8} "
             f"{'alarms':<44} {'Pm':>7} {'critical in':<18}"]
    alarms_by_joint: dict[int, list[str]] = {}
    for a in stats.get("alarms", []):
        alarms_by_joint.setdefault(a["joint"], []).append(f"{a['quantity']}@{a['cycle']}")
    for joint in sorted(last_symptoms):
        rec = last_symptoms[joint]
        wear = rec.get("wear", {})
        pm = [d.get("miss_probability") for d in rec.get("decisions", {}).values()
              if d.get("miss_probability") is not None]
        alarms = ", ".join(alarms_by_joint.get(joint, [])) or "none"
        alarms = alarms if len(alarms) <= 44 else alarms[:43] + "…"      # cut: said, not hidden
        stages = {(d.get("calibration") or {}).get("stage") for d in rec.get("decisions", {}).values()} - {None}
        stage = stages.pop() if len(stages) == 1 else ("mixed" if stages else "-")
        lines.append(f"{joint:>5} {rec.get('cycle', 0) + 1:>6} {wear_text(wear):>16} "
                     f"{fmt(wear.get('temperature'), '.1f'):>8} {stage:>8} {coverage_text(rec):>8} {alarms:<44} "
                     f"{fmt(min(pm) if pm else None, '.2g'):>7} {prognosis_text(rec.get('prognosis')):<18}")
    for joint, alarm in sorted((raised or {}).items()):
        if (alarm.get("prognosis") or {}).get("text"):
            lines.append(f"joint {joint}: fault raised at cycle {alarm['cycle']}: {alarm['prognosis']['text']}")
    lines.append(f"false alarms: {setting}; Pm: smallest estimated miss probability over the joint's detectors; "
                 "critical in: days until the critical wear, median (10–90 %) at the measured cycle rate; "
                 "tested %: share of the cycles the joint's detectors tested since they first learned")
    return "\n".join(lines)


def open_mapped_source(cfg: AgentConfig, path: str | None, table: bool = False) -> tuple[AgentConfig, Any]:
    """``(config, source)`` for ``--mapping`` (``(cfg, None)`` without one: our frames). A mapping that
    does not load or does not match its DBC/EDS, or a trace mapping where the input is frames (not a
    ``table``), exits with code 2."""
    if not path:
        return cfg, None
    from edge_monitor.pipeline.agent_config import config_for
    from edge_monitor.sources.foreign_source import open_source
    from protocol.signal_mapping import MappingError, load_mapping
    try:
        mapping = load_mapping(path)
        if mapping.kind == "trace" and not table:
            raise MappingError(f"{path} is a trace mapping: it reads a CSV/Parquet table (edge-monitor replay "
                               "TABLE.csv --mapping …); CAN frames need a dbc or cia402 mapping")
        cfg = config_for(cfg, mapping)
        return cfg, open_source(mapping, cfg)
    except ValueError as exc:       # MappingError and what the DBC/EDS parsers raise
        print(f"edge-monitor: mapping error: {exc}", file=sys.stderr)
        raise SystemExit(EXIT_USAGE) from None
    except OSError as exc:          # a mapping, DBC or EDS file that cannot be read
        print(f"edge-monitor: {exc}", file=sys.stderr)
        raise SystemExit(EXIT_FAILURE) from None
