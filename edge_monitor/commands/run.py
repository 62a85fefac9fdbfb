"""``edge-monitor run --link LINK``: the agent beside a controller, live.

Receives frames from a CAN link, publishes per-cycle symptoms over Zenoh (and optionally JSONL and
Rerun), persists learned models in ``--state-dir`` and shuts down cleanly on SIGINT/SIGTERM
(state saved, Zenoh undeclared, Rerun flushed).
"""

from __future__ import annotations

import argparse
import logging
import signal
import sys
import threading
from contextlib import ExitStack
from typing import Any

from edge_monitor.pipeline.agent import Agent
from edge_monitor.commands.common import add_config_arguments, load_agent_config, open_state_store
from edge_monitor.config import AgentConfig
from edge_monitor.pipeline.frame_source import LiveSource
from edge_monitor.sinks.jsonl import JsonlSink
from edge_monitor.pipeline.live import LiveRunner
from edge_monitor.sinks.zenoh_session import ZenohOptions, ZenohSetupError

log = logging.getLogger(__name__)


def add_parser(subparsers: argparse._SubParsersAction) -> None:
    p = subparsers.add_parser("run", help="monitor a live CAN link", description=__doc__)
    p.add_argument("--link", help="socketcan:IFACE | slcan:DEVICE_OR_URL | virtual:NAME "
                                  "(omit to use python-can's --interface/--channel or CAN_*/~/.canrc config)")
    p.add_argument("-i", "--interface", help="python-can interface (when --link is not given)")
    p.add_argument("-c", "--channel", help="python-can channel (when --link is not given)")
    p.add_argument("-b", "--bitrate", type=int, help="CAN bitrate")
    add_config_arguments(p)
    ZenohOptions.add_arguments(p)
    p.add_argument("--no-zenoh", action="store_true", help="do not publish over Zenoh")
    p.add_argument("--rerun", default=None, help="off | save:PATH | spawn | connect:URL (default: config, off)")
    p.add_argument("--duration", type=float, help="stop after this many seconds")
    p.add_argument("--max-cycles", type=int, help="stop after this many cycles")
    p.add_argument("--idle-stop", type=float, help="stop after this many seconds without frames")
    p.add_argument("--maintenance", type=int, action="append", default=[], metavar="JOINT",
                   help="declare a gearbox replacement / service on JOINT at start: relearn its nominal models "
                        "(while running: put anything on Zenoh key edge/<robot>/<joint>/maintenance)")
    p.set_defaults(func=run)


def build_sinks(cfg: AgentConfig, args: argparse.Namespace, stack: ExitStack,
                state_provider=None, recording_id: str | None = None) -> list[Any]:
    """JSONL, Zenoh and Rerun sinks as configured; failures to open say what to fix."""
    from edge_monitor.sinks.adapters import RerunViewSink, ZenohSink
    sinks: list[Any] = []
    if cfg.jsonl:
        sinks.append(JsonlSink(cfg.jsonl, include_alarms=False))
    if not getattr(args, "no_zenoh", False):
        from edge_monitor.sinks.zenoh_publisher import SymptomPublisher
        from edge_monitor.sinks.zenoh_session import open_session
        options = ZenohOptions.from_args(args)
        session = open_session(options)
        stack.callback(session.close)
        publisher = SymptomPublisher(session, cfg.robot, cfg.joints or (), state_provider=state_provider)
        sinks.append(ZenohSink(publisher))
        log.info("zenoh: %s", options.describe())
    spec = getattr(args, "rerun", None) or cfg.rerun
    if spec and spec != "off":
        from edge_monitor.sinks.rerun_view import RerunSink
        sinks.append(RerunViewSink(RerunSink.open(spec, recording_id=recording_id, fallback_save="edge-monitor.rrd")))
    return sinks


def install_signal_handlers(stop: threading.Event) -> None:
    def handler(signum, _frame):
        log.warning("signal %d: stopping (state is saved)", signum)
        stop.set()
    if threading.current_thread() is threading.main_thread():
        signal.signal(signal.SIGINT, handler)
        signal.signal(signal.SIGTERM, handler)


def run(args: argparse.Namespace) -> int:
    from protocol.links import LinkError, is_log_file, open_bus
    logging.getLogger("edge_monitor.status").setLevel(logging.INFO)
    cfg = load_agent_config(args)
    if args.link and is_log_file(args.link):
        print(f"edge-monitor run: {args.link} is a log file; use `edge-monitor replay {args.link}`", file=sys.stderr)
        return 2
    store = open_state_store(cfg)
    with ExitStack() as stack:
        agent_ref: dict[str, Agent] = {}
        try:
            sinks = build_sinks(cfg, args, stack, state_provider=lambda j: _joint_state(agent_ref, j))
        except (ZenohSetupError, ValueError) as exc:
            print(f"edge-monitor run: {exc}", file=sys.stderr)
            return 2
        agent = Agent(cfg, sinks=sinks, state_store=store)
        agent_ref["agent"] = agent
        for joint in args.maintenance:
            try:
                agent.declare_maintenance(joint)
            except ValueError as exc:
                print(f"edge-monitor run: --maintenance {joint}: {exc}", file=sys.stderr)
                return 2
        session = next((s.publisher.session for s in sinks if hasattr(s, "publisher")), None)
        if session is not None:
            stack.callback(listen_for_maintenance(session, cfg.robot, agent).undeclare)
        try:
            bus = open_bus(args.link, interface=args.interface, channel=args.channel, bitrate=args.bitrate)
        except LinkError as exc:
            print(f"edge-monitor run: cannot open the CAN link: {exc}", file=sys.stderr)
            agent.close()
            return 2
        stack.callback(bus.shutdown)
        runner = LiveRunner(agent, LiveSource(bus, maxsize=cfg.queue_size, block_size=cfg.block_size),
                            status_interval_s=cfg.status_interval_s)
        install_signal_handlers(runner.stop_event)
        try:
            runner.run(duration_s=args.duration, max_cycles=args.max_cycles, idle_stop_s=args.idle_stop)
        finally:
            agent.close()
    if runner.link_failure:
        print(f"edge-monitor run: stopped because the CAN link failed: {runner.link_failure}", file=sys.stderr)
        return 1
    return 0


def listen_for_maintenance(session, robot: str, agent: Agent):
    """Subscribe to ``edge/<robot>/<joint>/maintenance``: any put there declares a gearbox replacement
    or service of that joint (the agent relearns its nominal models and clears its alarms)."""

    def on_sample(sample) -> None:
        key = str(sample.key_expr)
        try:
            joint = int(key.split("/")[2])
            agent.declare_maintenance(joint)
        except Exception as exc:   # never raise into Zenoh's thread
            log.error("maintenance declaration on %s ignored: %s", key, exc)

    return session.declare_subscriber(f"edge/{robot}/*/maintenance", on_sample)


def _joint_state(agent_ref: dict[str, Agent], joint: int) -> dict:
    """Answer for the read-only state queryable: the joint's models and detector state."""
    agent = agent_ref.get("agent")
    return agent.joint_state(joint) if agent is not None else {"joint": joint, "known": False}
