#!/usr/bin/env python3
"""Soak / fault run: the simulated controller streams with injected link faults into the live agent,
then every injected fault is reconciled against the agent's counters.

In one process over python-can's ``virtual`` bus (default; works everywhere), or across processes
over any link the simulator and agent can both open (``--link slcan:…`` with ``--peer-link``, or
``socketcan:vcan0`` for both where the kernel has vcan). Prints a status line while running and a
reconciliation table at the end; exit code 1 if anything does not add up.

    .venv/bin/python tools/soak.py --cycles 20 --joints 6 --faults drop=0.001,corrupt=0.001,duplicate=0.0005,reorder=0.0005
"""

from __future__ import annotations

import argparse
import json
import logging
import sys
import tempfile
import threading
from pathlib import Path

from edge_monitor.config import AgentConfig
from edge_monitor.pipeline.agent import Agent
from edge_monitor.pipeline.frame_source import LiveSource
from edge_monitor.pipeline.live import LiveRunner
from protocol.links import open_bus
from sim_controller.config import SimConfig
from sim_controller.faults import FaultSpec
from sim_controller.output import run as run_simulator

log = logging.getLogger("soak")


def counter_row(lost: int, f: dict, wrong_sequence: int) -> tuple[str, int, int, bool]:
    """Counter gaps: exact for drops, corruption and reordering; with silences, delays and restarts a
    long gap makes the receiver resynchronise instead of counting each frame, so only a bound holds."""
    exact = f["dropped"] + f["corrupted"] + wrong_sequence
    if not (f.get("silenced") or f.get("delayed") or f.get("restarts")):
        return ("counter_lost = dropped + corrupted + stale", lost, exact, lost == exact)
    bound = exact + f.get("silenced", 0) + f.get("delayed", 0)
    return ("counter_lost <= dropped + corrupted + stale + silenced + delayed", lost, bound,
            f["dropped"] <= lost <= bound)


def reconcile(stats: dict, truth: dict, received: int) -> list[tuple[str, int, int, bool]]:
    """(check, agent figure, expected from the injected faults, ok) rows."""
    f = truth["faults"]
    wrong_sequence = stats["details"]["wrong_sequence"]
    rows = [
        ("frames received = frames sent", stats["frames_total"], truth["frames_sent"],
         stats["frames_total"] == truth["frames_sent"]),
        ("crc_errors = corrupted", stats["crc_errors"], f["corrupted"], stats["crc_errors"] == f["corrupted"]),
        ("repeated = duplicated", stats["repeated"], f["duplicated"], stats["repeated"] == f["duplicated"]),
        counter_row(stats["counter_lost"], f, wrong_sequence),
        ("frames reaching the agent's queue", received, truth["frames_sent"], received == truth["frames_sent"]),
    ]
    return rows


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--cycles", type=int, default=10)
    ap.add_argument("--joints", type=int, default=6)
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--faults", default="drop=0.001,corrupt=0.001,duplicate=0.0005,reorder=0.0005")
    ap.add_argument("--speedup", type=float, default=None, help="pace the simulator (default: unpaced)")
    ap.add_argument("--link", default="virtual:soak", help="the simulator's link (default virtual:soak)")
    ap.add_argument("--peer-link", default=None, help="the agent's link if it differs (e.g. other pty end)")
    ap.add_argument("--json", action="store_true", help="print the reconciliation as JSON")
    args = ap.parse_args()
    logging.basicConfig(level=logging.INFO, format="%(asctime)s %(name)s: %(message)s")
    logging.getLogger("edge_monitor.status").setLevel(logging.INFO)

    config = SimConfig(joints=args.joints, cycles=args.cycles, seed=args.seed, faults=FaultSpec.parse(args.faults))
    agent = Agent(AgentConfig(status_interval_s=5.0))
    bus = open_bus(args.peer_link or args.link, receive_own_messages=False)
    runner = LiveRunner(agent, LiveSource(bus, maxsize=1 << 20), status_interval_s=5.0)
    thread = threading.Thread(target=runner.run, name="agent", daemon=True)
    thread.start()
    with tempfile.TemporaryDirectory() as tmp:
        truth_path = Path(tmp) / "truth.jsonl"
        summary = run_simulator(config, args.link, speedup=args.speedup, truth_path=truth_path)
        truth = json.loads(truth_path.read_text().splitlines()[-1])
    runner.wait_drained(quiet_s=0.5, limit_s=120)
    runner.stop_event.set()
    thread.join(timeout=30)
    bus.shutdown()
    stats = agent.run_statistics()
    rows = reconcile(stats, truth, runner.source.listener.received)
    ok = all(r[3] for r in rows) and runner.source.listener.dropped == 0
    if args.json:
        print(json.dumps({"rows": [dict(zip(("check", "agent", "expected", "ok"), r)) for r in rows],
                          "queue_dropped": runner.source.listener.dropped, "faults": truth["faults"],
                          "cycles": stats["cycles"], "symptoms": stats["symptoms"], "ok": ok}, indent=2))
    else:
        print(f"simulated {summary.simulated_s:.0f} s ({summary.cycles} cycles, {args.joints} joints) in "
              f"{summary.wall_s:.1f} s; faults injected: {truth['faults']}")
        for check, got, want, good in rows:
            print(f"  {'ok ' if good else 'BAD'} {check:<42} agent {got:>9}  expected {want:>9}")
        print(f"  queue dropped {runner.source.listener.dropped}; cycles {stats['cycles']}, "
              f"symptoms {stats['symptoms']}")
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
