"""``edge-monitor demo``: the whole system in one command, on embedded defaults.

Starts the simulated controller as a separate process streaming over a pseudo-terminal slcan link
(SocketCAN ``vcan0`` where the kernel has it) at the simulator's defaults (±8 % individual
variation, the lubricant warming from 30 °C) with a wear ramp on one joint, runs the agent on the
other end of the link, publishes over Zenoh (peer mode, loopback, multicast scouting off), counts
what an independent Zenoh subscriber receives, records to Rerun (and spawns the viewer when a
display is available), then prints a summary table.
"""

from __future__ import annotations

import argparse
import json
import logging
import math
import os
import subprocess
import sys
import threading
import time
from contextlib import ExitStack
from pathlib import Path

from edge_monitor.app import Outputs, build_app
from edge_monitor.commands.common import open_state_store, prognosis_summary, summary_table
from edge_monitor.commands.output_paths import check_parent
from edge_monitor.errors import ConfigError
from edge_monitor.features.joint_model_learning import ModelConfig
from edge_monitor.features.kl_monitor import KLConfig
from edge_monitor.features.segmentation import PlateauConfig
from edge_monitor.pipeline.agent_config import AgentConfig
from edge_monitor.pipeline.decision_config import DecisionConfig
from edge_monitor.pipeline.live import LiveRunner
from edge_monitor.records import to_json
from edge_monitor.run_failures import setup_failure
from edge_monitor.sinks.base import LastSymptomSink
from edge_monitor.sinks.jsonl import JsonlOpenError
from edge_monitor.sinks.loopback import free_loopback_port
from edge_monitor.sinks.zenoh_session import ZenohOptions
from edge_monitor.sources.frame_source import LiveSource
from protocol.console import (
    EXIT_FAILURE,
    UsageError,
    interrupted_exit,
    verbosity,
)

log = logging.getLogger(__name__)

#: Speeds of the demo's test cycle [rad/s]: `edge-monitor design --points 4 --json` at the default
#: design point (ξ' = 40 °C, ϖ' = 35), rounded to 0.1 rad/s.
DEMO_SPEEDS = (31.6, 36.6, 41.6, 46.6)
DEMO_JOINTS = 2
DEMO_CYCLES = 160
WORN_JOINT = 1
#: Where the demo writes when not told (made with its parents; a folder given with --out must have its parent).
DEFAULT_OUT = "out/demo"
#: Cycles the worn joint's wear takes from 0 to 60 (critical: 35): a medium ramp, 0.5 per cycle.
RAMP_CYCLES = 120


def add_parser(subparsers: argparse._SubParsersAction) -> None:
    p = subparsers.add_parser("demo", help="simulated controller + agent + Zenoh + Rerun in one command",
                              description=__doc__)
    p.add_argument("--cycles", type=int, default=DEMO_CYCLES, help=f"test cycles to simulate (default {DEMO_CYCLES})")
    p.add_argument("--joints", type=int, default=DEMO_JOINTS,
                   help=f"joints (default {DEMO_JOINTS}; joint {WORN_JOINT} wears, joint 0 of a 1-joint robot)")
    p.add_argument("--speedup", type=float, default=8.0,
                   help="simulated seconds per wall second (slcan over a pty carries ~15k frames/s)")
    p.add_argument("--seed", type=int, default=7, help="the simulator's random seed (default 7; ≥ 0)")
    p.add_argument("-o", "--out", default=DEFAULT_OUT, help="directory for the recording, symptoms, truth and state")
    p.add_argument("--rerun", default=None,
                   help="off | save:PATH | spawn | connect:URL (default: spawn with a display, else "
                        "save:<out>/demo.rrd)")
    p.add_argument("--link", default="auto", choices=("auto", "pty", "vcan"),
                   help="auto | pty | vcan (auto: vcan0 if available, else pty)")
    p.add_argument("--json", action="store_true",
                   help="print the run summary as JSON instead of the table (it is always written to "
                        "<out>/summary.json; schema: edge-monitor schema summary)")
    p.add_argument("--nominal-cycles", type=int, default=60,
                   help="cycles the detectors learn from before monitoring (default 60, as the agent)")
    p.set_defaults(func=run)


def demo_config(out: Path, nominal_cycles: int) -> AgentConfig:
    """The demo's agent configuration: short learning phases so detection fits in minutes."""
    return AgentConfig(
        robot="demo-robot",
        segmentation=PlateauConfig(speeds=DEMO_SPEEDS),
        kl=KLConfig(n_nominal_cycles=5),
        decision=DecisionConfig(n_nominal=nominal_cycles),
        state_dir=str(out / "state"), jsonl=str(out / "symptoms.jsonl"),
        status_interval_s=5.0,
    )


def worn_joint(joints: int) -> int:
    """The joint the demo wears: :data:`WORN_JOINT`, or the last one of a robot with fewer joints."""
    return min(WORN_JOINT, joints - 1)


def sim_command(link: str, args: argparse.Namespace, truth: Path) -> list[str]:
    """The simulator at its default individual variation (±8 % per joint) and thermal drift; the wear
    ramp (0 → 60 over ``RAMP_CYCLES``) starts 5 cycles after the agent has learned the joint's model and
    its nominal behaviour."""
    wear_start = min(ModelConfig().learning_cycles + args.nominal_cycles + 5, args.cycles - 1)
    return [sys.executable, "-m", "sim_controller.cli", "run", "--link", link,
            "--joints", str(args.joints), "--cycles", str(args.cycles), "--seed", str(args.seed),
            "--speeds", ",".join(str(v) for v in DEMO_SPEEDS), "--plateau-time", "0.9",
            "--speedup", str(args.speedup),
            "--wear-ramp", f"{worn_joint(args.joints)}:{wear_start}:{wear_start + RAMP_CYCLES}:0:60",
            "--truth", str(truth), *(["-q"] if verbosity(args) < 0 else [])]


def choose_link(kind: str, stack: ExitStack) -> tuple[str, str, str]:
    """(sim link, agent link, description)."""
    from protocol.links import PtyPair, vcan_available
    if kind == "vcan" or (kind == "auto" and vcan_available("vcan0")):
        return "socketcan:vcan0", "socketcan:vcan0", "SocketCAN vcan0"
    pair = stack.enter_context(PtyPair())
    return f"slcan:{pair.a}", f"slcan:{pair.b}", f"slcan over pty {pair.a} <-> {pair.b}"


def rerun_spec(requested: str | None, out: Path) -> str:
    if requested:
        return requested
    import importlib.util
    if importlib.util.find_spec("rerun") is None:     # a headless installation: the demo without its recording
        log.warning("the Rerun viewer is not installed (pip install 'joint-wear-monitor[viewer]'): the demo runs "
                    "without a recording")
        return "off"
    has_display = bool(os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY"))
    return "spawn" if has_display else f"save:{out / 'demo.rrd'}"


def _checked_config(args: argparse.Namespace, out: Path) -> AgentConfig:
    """The demo's configuration, or UsageError (exit 2) for an option the demo or its simulator refuses."""
    if args.cycles < 2 or args.joints < 1 or args.joints > 8:
        raise UsageError("need --cycles >= 2 and 1 <= --joints <= 8")
    if not (math.isfinite(args.speedup) and args.speedup >= 0):
        raise UsageError(f"--speedup {args.speedup}: must be a number ≥ 0 (0: as fast as the link carries)")
    if args.seed < 0:
        raise UsageError(f"--seed {args.seed}: must be ≥ 0")
    if out.exists() and not out.is_dir():
        raise UsageError(f"--out {out}: is a file; give a folder for the demo's outputs")
    if args.out != DEFAULT_OUT:             # a typo in --out must not make a directory tree
        check_parent(out, "--out")
    try:
        return demo_config(out, args.nominal_cycles)
    except ConfigError as exc:
        raise UsageError(f"--nominal-cycles {args.nominal_cycles}: {exc}") from None


def run(args: argparse.Namespace) -> int:
    from protocol.links import LinkError, open_bus
    out = Path(args.out)
    cfg = _checked_config(args, out)        # every option checked before --out is touched
    if verbosity(args) >= 0:        # the demo shows its status line unless -q
        logging.getLogger("edge_monitor.status").setLevel(logging.INFO)
    out.mkdir(parents=True, exist_ok=True)
    for stale in ("symptoms.jsonl", "truth.jsonl", "state/agent_state.json"):
        (out / stale).unlink(missing_ok=True)
    port = free_loopback_port()
    endpoint = f"tcp/127.0.0.1:{port}"
    spec = rerun_spec(args.rerun, out)
    started = time.monotonic()
    with ExitStack() as stack:
        sim_link, agent_link, link_desc = choose_link(args.link, stack)
        if verbosity(args) >= 0 and not args.json:
            print(f"demo: link {link_desc}; zenoh peer on {endpoint}; rerun {spec}; {args.cycles} cycles, "
                  f"{args.joints} joints, wear ramp on joint {worn_joint(args.joints)}", flush=True)
        try:
            app = build_app(cfg, Outputs(jsonl=cfg.jsonl, zenoh=ZenohOptions(mode="peer", listen=[endpoint]),
                                         rerun=spec, rerun_fallback=str(out / "demo.rrd"), maintenance=True),
                            stack, open_state_store(cfg), live=True)
        except JsonlOpenError as exc:   # the output folder's symptoms.jsonl cannot be used
            print(f"edge-monitor demo: {exc}", file=sys.stderr)
            return EXIT_FAILURE
        except ValueError as exc:      # ZenohSetupError, RerunSetupError: say what to fix
            return setup_failure("demo", exc)
        agent = app.agent
        last = LastSymptomSink()
        agent.sinks.append(last)
        subscriber = stack.enter_context(_CountingSubscriber(endpoint))
        try:
            bus = open_bus(agent_link)
        except LinkError as exc:
            print(f"edge-monitor demo: cannot open the agent's end of the link: {exc}", file=sys.stderr)
            return EXIT_FAILURE
        stack.callback(bus.shutdown)
        runner = LiveRunner(agent, LiveSource(bus, maxsize=cfg.queue_size, block_size=cfg.block_size),
                            status_interval_s=cfg.status_interval_s)
        agent_thread = threading.Thread(target=runner.run, name="agent", daemon=True)
        agent_thread.start()
        truth = out / "truth.jsonl"
        sim = subprocess.Popen(sim_command(sim_link, args, truth), stdin=subprocess.DEVNULL)
        interrupted: KeyboardInterrupt | None = None
        try:
            sim_rc = sim.wait()
            runner.wait_drained(quiet_s=2.0)
        except KeyboardInterrupt as exc:    # Ctrl-C or SIGTERM: stop the simulator, still show what was seen
            interrupted = exc
            sim.terminate()
            sim_rc = sim.wait()
        runner.stop_event.set()
        agent_thread.join(timeout=30)
        agent.finish(close_open_cycle=True)
        frames = agent.run_statistics()
        published = app.symptoms_published()
        subscriber.wait_for(published, timeout=10.0)
        received = subscriber.count()
    rrd = spec.partition(":")[2] if spec.startswith("save:") else None
    summary = {**frames, "prognosis": prognosis_summary(last.last), "demo": {
        "symptoms_published": published, "symptoms_received": received, "rrd": rrd, "rerun": spec,
        "frames_sent": _frames_sent(truth), "simulator_exit_code": sim_rc,
        "wall_s": round(time.monotonic() - started, 1), "link": link_desc,
        "arl0_cycles": frames["details"].get("arl0_cycles", cfg.decision.arl0),
        "jsonl": cfg.jsonl, "truth": str(truth)}}
    (out / "summary.json").write_text(to_json(summary, indent=2) + "\n")
    if args.json:
        print(to_json(summary, indent=2))
    elif verbosity(args) >= 0:              # -q: no summary
        print(summary_table(last.last, frames, cfg.decision, last.raised))
        print(f"symptoms published {published}, received by an independent Zenoh subscriber {received}; "
              f"frames {frames['frames_total']} (ok {frames['frames_ok']}); wall {summary['demo']['wall_s']} s")
        if rrd:
            print(f"recording: {rrd}  (open with: {rerun_command()} {rrd})")
    if interrupted is not None:
        return interrupted_exit("edge-monitor demo", interrupted)
    return 0 if sim_rc == 0 else EXIT_FAILURE


def rerun_command() -> str:
    """How to run the Rerun viewer of this installation: ``rerun`` when it is on PATH, else its full path."""
    import shutil
    beside = Path(sys.executable).parent / "rerun"
    found = shutil.which("rerun")
    return "rerun" if found and (not beside.exists() or Path(found).resolve() == beside.resolve()) else str(beside)


def _frames_sent(truth: Path) -> int | None:
    try:
        last = truth.read_text().strip().splitlines()[-1]
        return json.loads(last).get("frames_sent")
    except (OSError, IndexError, ValueError):
        return None


class _CountingSubscriber:
    """An independent Zenoh session (peer, connected to the agent's endpoint) counting symptoms."""

    def __init__(self, endpoint: str) -> None:
        self.endpoint = endpoint

    def __enter__(self) -> "_CountingSubscriber":
        from edge_monitor.sinks.zenoh_publisher import SymptomSubscriber
        from edge_monitor.sinks.zenoh_session import open_session
        self.session = open_session(ZenohOptions(mode="peer", connect=[self.endpoint]))
        self.sub = SymptomSubscriber(self.session, "edge/**", history=True)
        return self

    def count(self) -> int:
        return len({(r["joint"], r["cycle"]) for r in self.sub.records("symptom")})

    def wait_for(self, n: int, timeout: float) -> bool:
        return self.sub.wait_for(lambda _: self.count() >= n, timeout)

    def __exit__(self, *exc: object) -> None:
        self.sub.close()
        self.session.close()
