#!/usr/bin/env python3
"""Soak with chaos: simulator, agent, Zenoh router and an independent subscriber as separate processes
over the pty slcan link; kills and restarts on a seeded schedule; every frame, fault and symptom
reconciled at the end (docs/RELIABILITY.md, "A real soak").

    .venv/bin/python tools/soak/soak.py --duration 60 --json            # `make soak`
    .venv/bin/python tools/soak/soak.py --duration 1800 --json --keep out/soak

Processes: ``sim-controller run`` (paced at ``--speedup`` × real time, link faults), ``edge-monitor run``
(state dir, JSONL, Zenoh client of the router), ``edge-monitor router`` on a free loopback port,
``tools/soak/soak_subscriber.py`` (writes every symptom it receives). The pty bridge runs in this process
and reports where every byte went (tools/soak/soak_link.py). Chaos (``--no-chaos`` to disable), one action at
a time, each waiting until the agent has processed two cycle starts afterwards: kill -9 of the agent's
process group then a restart on the same state, a router kill and restart, a bus silence (SIGSTOP /
SIGCONT of the simulator), a controller restart (SIGTERM, then a new simulator process: counters from 0).
``--link socketcan:IFACE`` runs over SocketCAN with a bus monitor instead of the pty tap (kill split
approximate). A status line goes to stderr every ~10 s; ``--json`` prints the result as one JSON object
on stdout. Exit code 0 when every rule holds, 1 otherwise, 130 on Ctrl-C; every process is stopped on exit.
"""

from __future__ import annotations

import argparse
import contextlib
import json
import logging
import os
import random
import signal
import subprocess
import sys
import tempfile
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable

TOOLS = Path(__file__).resolve().parent
sys.path[:0] = [str(TOOLS.parents[1]), str(TOOLS)]

import zenoh  # noqa: E402
from soak_link import CanMonitorTap, LinkLedger, PtyLinkTap  # noqa: E402
from soak_report import (  # noqa: E402
    LifeRecord,
    Sample,
    SimRecord,
    fault_report,
    frame_report,
    read_symptom_lines,
    resource_report,
    symptom_report,
    write_samples,
)

from edge_monitor.sinks.keys import HEALTH, agent_key  # noqa: E402
from edge_monitor.sinks.loopback import free_loopback_port  # noqa: E402
from edge_monitor.sinks.zenoh_session import ZenohOptions, open_session  # noqa: E402
from protocol.links import PtyPair  # noqa: E402

log = logging.getLogger("soak")

ROBOT = "soak"
SPEEDS = (8.7, 41.7, 133.5)        # a 9 s test cycle at --plateau-time 0.8
PLATEAU_TIME = 0.8
CHAOS_KINDS = ("agent_kill", "router_restart", "bus_silence", "controller_restart")
LINK_BUFFER = 4 << 20              # pty bridge buffer per direction [bytes]
STATUS_EVERY_S = 10.0
START_TIMEOUT_S = 180.0            # a process must be up (imports on a busy machine) within this
SETTLE_TIMEOUT_S = 300.0           # an action must be digested (two cycle starts) within this
AGENT_CONFIG = f"""robot = "{ROBOT}"
status_interval_s = 1.0
[segmentation]
speeds = [{", ".join(str(v) for v in SPEEDS)}]
"""


def parse_args(argv: list[str] | None = None) -> argparse.Namespace:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--duration", type=float, default=60.0, help="seconds of streaming (at least; default 60)")
    ap.add_argument("--json", action="store_true", help="print the result as one JSON object on stdout")
    ap.add_argument("--seed", type=int, default=1, help="seed of the chaos schedule and the simulator")
    ap.add_argument("--link", default="pty", help="pty (default) or socketcan:IFACE")
    ap.add_argument("--speedup", type=float, default=4.0, help="simulated seconds per wall second (default 4)")
    ap.add_argument("--joints", type=int, default=2)
    ap.add_argument("--faults", default="drop=0.001,corrupt=0.001,duplicate=0.0005,reorder=0.0005",
                    help="the simulator's link faults")
    ap.add_argument("--no-chaos", action="store_true", help="no kills, restarts or silences")
    ap.add_argument("--chaos-interval", type=float, default=60.0,
                    help="mean seconds between chaos actions (at least one of each kind; default 60)")
    ap.add_argument("--downtime", type=float, default=2.0,
                    help="seconds an agent or router stays dead, or the bus silent (default 2)")
    ap.add_argument("--sample-interval", type=float, default=2.0, help="seconds between RSS/CPU samples")
    ap.add_argument("--warmup", type=float, default=10.0, help="seconds of each agent life left out of the RSS slope")
    ap.add_argument("--slope-last", type=float, default=3600.0,
                    help="also the RSS slope over the last this many seconds, for runs at least twice as long "
                         "(default 3600: the last hour of a 2-hour run)")
    ap.add_argument("--keep", metavar="DIR", help="keep logs, truth, JSONL and state here (default: a temp dir)")
    ap.add_argument("-v", "--verbose", action="store_true")
    return ap.parse_args(argv)


def chaos_plan(duration: float, interval: float, seed: int) -> list[tuple[float, str]]:
    """(time, kind), deterministic from ``seed``: every kind once per round of four, in a seeded order,
    at evenly spaced slots between 10 % and 85 % of the duration, jittered within their slot."""
    rng = random.Random(seed)
    n = max(len(CHAOS_KINDS), round(duration / interval))
    kinds: list[str] = []
    while len(kinds) < n:
        kinds += rng.sample(CHAOS_KINDS, len(CHAOS_KINDS))
    slot = 0.75 * duration / n
    return [(0.1 * duration + slot * (i + rng.uniform(0.2, 0.8)), kind) for i, kind in enumerate(kinds[:n])]


def wait_for(predicate: Callable[[], Any], timeout: float, what: str, poll_s: float = 0.1,
             tick: Callable[[], None] | None = None) -> bool:
    """Poll until ``predicate()`` holds (calling ``tick`` meanwhile); False and a warning on timeout."""
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if tick is not None:
            tick()
        if predicate():
            return True
        time.sleep(poll_s)
    log.warning("gave up waiting for %s after %.0f s", what, timeout)
    return bool(predicate())


class Proc:
    """A child in its own process group, output to log files; stopped with its group."""

    def __init__(self, name: str, cmd: list[str], work: Path) -> None:
        self.name = name
        self.stdout = work / f"{name}.out"
        self.stderr = work / f"{name}.log"
        with open(self.stdout, "w") as out, open(self.stderr, "a") as err:
            self.popen = subprocess.Popen(cmd, stdout=out, stderr=err, stdin=subprocess.DEVNULL,
                                          start_new_session=True)
        self.pid = self.popen.pid
        log.debug("%s started (pid %d): %s", name, self.pid, " ".join(cmd))

    def signal_group(self, signum: int) -> None:
        with contextlib.suppress(ProcessLookupError, PermissionError):
            os.killpg(self.pid, signum)

    def alive(self) -> bool:
        return self.popen.poll() is None

    def stop(self, signum: int = signal.SIGTERM, timeout: float = 60.0) -> int:
        """Signal the group and wait; SIGKILL after ``timeout``. The exit code."""
        self.signal_group(signal.SIGCONT)
        self.signal_group(signum)
        try:
            return self.popen.wait(timeout)
        except subprocess.TimeoutExpired:
            log.warning("%s did not stop within %.0f s: killed", self.name, timeout)
            self.signal_group(signal.SIGKILL)
            return self.popen.wait()

    def output(self) -> str:
        return self.stdout.read_text(errors="replace") if self.stdout.exists() else ""


class LineCount:
    """Lines of a growing file, counted from where the last call stopped (the status line must not
    re-read a JSONL of tens of MB every 10 s)."""

    def __init__(self, path: Path) -> None:
        self.path, self.offset, self.lines = path, 0, 0

    def count(self) -> int:
        with contextlib.suppress(OSError), open(self.path, "rb") as f:
            f.seek(self.offset)
            data = f.read()
            self.offset += len(data)
            self.lines += data.count(b"\n")
        return self.lines


class HealthWatch:
    """The soak's own Zenoh session: the agent's health records, each with its arrival time."""

    def __init__(self, endpoint: str) -> None:
        self.session = open_session(ZenohOptions(mode="client", connect=[endpoint]))
        self.records: list[dict[str, Any]] = []
        self._sub = self.session.declare_subscriber(agent_key(ROBOT, HEALTH), self._on_sample)

    def _on_sample(self, sample: zenoh.Sample) -> None:
        with contextlib.suppress(ValueError):
            self.records.append(json.loads(sample.payload.to_string()))

    def latest(self, since: float, until: float | None = None) -> dict[str, Any] | None:
        """The newest record the agent made between ``since`` and ``until`` (its own clock, ``time``)."""
        fits = [r for r in list(self.records)
                if r.get("time", 0) >= since and (until is None or r.get("time", 0) <= until)]
        return max(fits, key=lambda r: r.get("frames_total", 0)) if fits else None

    def close(self) -> None:
        with contextlib.suppress(Exception):
            self._sub.undeclare()
        self.session.close()


def proc_cpu_rss(pid: int) -> tuple[float, float] | None:
    """(CPU seconds of the process group ``pid``, RSS MB of process ``pid``) from /proc; None if gone."""
    try:
        rss_kb = next(int(line.split()[1]) for line in Path(f"/proc/{pid}/status").read_text().splitlines()
                      if line.startswith("VmRSS:"))
    except (OSError, StopIteration, ValueError):
        return None
    ticks = 0
    for entry in os.listdir("/proc"):
        if not entry.isdigit():
            continue
        try:
            fields = Path(f"/proc/{entry}/stat").read_text().rsplit(")", 1)[1].split()
        except OSError:
            continue
        if int(fields[2]) == pid:                       # process group
            ticks += int(fields[11]) + int(fields[12])  # utime + stime
    return ticks / os.sysconf("SC_CLK_TCK"), rss_kb / 1024.0


@dataclass
class Counts:
    restarts: dict[str, int] = field(default_factory=lambda: dict.fromkeys(CHAOS_KINDS, 0))
    chaos_log: list[dict[str, Any]] = field(default_factory=list)


class Soak:
    """The processes, the link, the chaos and the bookkeeping of one soak."""

    def __init__(self, args: argparse.Namespace, work: Path, stack: contextlib.ExitStack) -> None:
        self.args, self.work, self.stack = args, work, stack
        self.ledger = LinkLedger()
        self.pair: PtyPair | None = None
        self.port = free_loopback_port()
        self.endpoint = f"tcp/127.0.0.1:{self.port}"
        self.tap, self.sim_link, self.agent_link, self.link_text = self._open_link(args.link)
        self.lives: list[LifeRecord] = []
        self.sims: list[SimRecord] = []
        self.counts = Counts()
        self.agent: Proc | None = None
        self.sim: Proc | None = None
        self.router: Proc | None = None
        self.subscriber: Proc | None = None
        self.health: HealthWatch | None = None
        self.started = time.monotonic()
        self.stream_started = 0.0
        self._last_sample = self._last_status = 0.0
        self._sample_lock = threading.Lock()
        self._sampler_stop = threading.Event()
        self._sampler = threading.Thread(target=self._sample_loop, name="rss-sampler", daemon=True)
        self._lines = {name: LineCount(work / name) for name in ("symptoms.jsonl", "received.jsonl")}
        (work / "agent.toml").write_text(AGENT_CONFIG)
        stack.callback(self._stop_all)
        stack.callback(self._stop_sampler)

    # -- link -------------------------------------------------------------------------------
    def _open_link(self, link: str) -> tuple[Any, str, str, str]:
        if link == "pty":
            pair = PtyPair(max_buffer=LINK_BUFFER)
            tap = PtyLinkTap(pair.b, self.ledger, window=LINK_BUFFER + (1 << 20))
            pair.observer = tap
            self.stack.callback(pair.close)
            self.pair = pair
            return tap, f"slcan:{pair.a}", f"slcan:{pair.b}", f"slcan over pty {pair.a} <-> {pair.b}"
        if link.startswith("socketcan:"):
            monitor = CanMonitorTap(link, self.ledger)
            self.stack.callback(monitor.close)
            return monitor, link, link, f"SocketCAN {link.split(':', 1)[1]} (bus monitor; kill split approximate)"
        raise SystemExit(f"soak: --link {link!r}: use pty or socketcan:IFACE")

    def backlog(self) -> int:
        return self.pair.backlog() if self.pair is not None else 0

    def quiet_link(self) -> None:
        """Wait until the link has moved every byte written so far, and account for it."""
        wait_for(lambda: self.backlog() == 0, 60.0, "the link to drain")
        self.tap.pump()

    # -- processes --------------------------------------------------------------------------
    def start_router(self) -> None:
        for attempt in range(20):
            proc = Proc("router", [str(Path(sys.executable).parent / "edge-monitor"), "router", "--port", str(self.port)],
                        self.work)
            if wait_for(lambda: "listening" in proc.output() or not proc.alive(), START_TIMEOUT_S, "the router"):
                if proc.alive():
                    self.router = proc
                    return
            log.info("router did not start (attempt %d, port %d busy?): retrying", attempt + 1, self.port)
            time.sleep(0.5)
        raise RuntimeError(f"the Zenoh router does not start on {self.endpoint}")

    def start_subscriber(self) -> None:
        proc = self.subscriber = Proc("subscriber", [
            sys.executable, str(TOOLS / "soak_subscriber.py"), "--connect", self.endpoint,
            "--key", f"edge/{ROBOT}/*/symptom", "--out", str(self.work / "received.jsonl")], self.work)
        if not wait_for(lambda: "subscriber ready" in proc.output(), START_TIMEOUT_S, "the subscriber"):
            raise RuntimeError("the subscriber did not start (see subscriber.log)")

    def start_agent(self) -> None:
        """Start an agent life on the current state and wait until it listens (its first health record)."""
        self.tap.announce("agent_started")
        t0 = time.time()
        self.agent = Proc(f"agent{len(self.lives)}", [
            sys.executable, "-m", "edge_monitor.cli", "run", "-v", "--link", self.agent_link,
            "--config", str(self.work / "agent.toml"), "--jsonl", str(self.work / "symptoms.jsonl"),
            "--state-dir", str(self.work / "state"), "--zenoh-mode", "client", "--zenoh-connect", self.endpoint,
            "--json"], self.work)
        self.lives.append(LifeRecord(len(self.lives), self.agent.pid, t0))
        assert self.health is not None
        health = self.health
        if not wait_for(lambda: health.latest(t0) is not None, START_TIMEOUT_S, "the agent's first health record",
                        tick=self.tick):
            raise RuntimeError(f"agent life {len(self.lives) - 1} did not start (see {self.agent.stderr.name})")
        if isinstance(self.tap, CanMonitorTap):
            self.tap.listening = True

    def start_sim(self) -> None:
        self.tap.announce("sim_started")
        index = len(self.sims)
        self.sims.append(SimRecord(index))
        self.sim = Proc(f"sim{index}", [
            sys.executable, "-m", "sim_controller.cli", "run", "--link", self.sim_link,
            "--joints", str(self.args.joints), "--cycles", "1000000", "--seed", str(self.args.seed + index),
            "--speeds", ",".join(str(v) for v in SPEEDS), "--plateau-time", str(PLATEAU_TIME),
            "--speedup", str(self.args.speedup), "--faults", self.args.faults,
            "--truth", str(self.work / f"truth{index}.jsonl"), "--json"], self.work)

    def stop_sim(self) -> None:
        """SIGTERM: the simulator finishes its frame block and writes its truth summary."""
        assert self.sim is not None
        rc = self.sim.stop(signal.SIGTERM, timeout=120.0)
        index = len(self.sims) - 1
        self.sims[index] = SimRecord.from_truth(index, self.work / f"truth{index}.jsonl")
        if rc != 0 or not self.sims[index].complete:
            log.warning("simulator %d ended with code %s, truth summary %s", index, rc,
                        "written" if self.sims[index].complete else "MISSING")
        self.quiet_link()

    def kill_agent(self) -> None:
        """kill -9 of the agent's process group (its calibration worker too)."""
        assert self.agent is not None
        self.sample(force=True)
        life = self.lives[-1]
        self.agent.signal_group(signal.SIGKILL)
        self.agent.popen.wait()
        life.ended, life.killed = time.time(), True
        self.link_closed()

    def stop_agent(self) -> None:
        """SIGTERM: the agent's normal end; its final counters come from --json."""
        assert self.agent is not None
        self.sample(force=True)
        rc = self.agent.stop(signal.SIGTERM, timeout=120.0)
        life = self.lives[-1]
        life.ended = time.time()
        summary = [line for line in self.agent.output().splitlines() if line.startswith("{")]
        if summary:
            final = json.loads(summary[-1])
            life.counters = final.get("health", final)     # the run summary carries the last health record
        else:
            log.warning("agent life %d printed no summary (exit code %s)", life.index, rc)
        self.quiet_link()
        self.link_closed()

    def link_closed(self) -> None:
        """After an agent's death: wait until the link has closed its life (every life closes once)."""
        if isinstance(self.tap, CanMonitorTap):
            self.tap.agent_down()
        wait_for(lambda: self.tap.closes >= len(self.lives), 60.0, "the link to notice the agent's end",
                 tick=self.tap.pump)

    def _stop_all(self) -> None:
        for proc in (self.sim, self.agent, self.subscriber, self.router):
            if proc is not None and proc.alive():
                proc.stop(signal.SIGKILL, timeout=30.0)
        if self.health is not None:
            self.health.close()

    # -- chaos ------------------------------------------------------------------------------
    def chaos(self, kind: str) -> None:
        log.info("chaos: %s at %.1f s", kind, time.monotonic() - self.stream_started)
        life, mark = self.ledger.open_life, self.frames_processed()
        getattr(self, "_chaos_" + kind)()
        self.counts.restarts[kind] += 1
        self.counts.chaos_log.append({"t": round(time.monotonic() - self.stream_started, 1), "kind": kind})
        self.settle(life, mark)

    def _chaos_agent_kill(self) -> None:
        """kill -9 while frames flow; frames meanwhile are lost; the restart happens on a silent bus
        (pyserial flushes the terminal's input when it opens it: frames then would vanish uncounted)."""
        self.kill_agent()
        self.idle(self.args.downtime)
        self.pause_sim()
        self.quiet_link()
        self.start_agent()
        self.resume_sim()

    def _chaos_router_restart(self) -> None:
        assert self.router is not None
        self.router.stop(signal.SIGKILL)
        self.idle(self.args.downtime)
        self.start_router()

    def _chaos_bus_silence(self) -> None:
        self.pause_sim()
        self.idle(self.args.downtime)
        self.resume_sim()

    def _chaos_controller_restart(self) -> None:
        self.stop_sim()
        self.start_sim()

    def pause_sim(self) -> None:
        assert self.sim is not None
        self.sim.signal_group(signal.SIGSTOP)

    def resume_sim(self) -> None:
        assert self.sim is not None
        self.sim.signal_group(signal.SIGCONT)

    def settle(self, life: Any, mark: int) -> None:
        """Until the agent has processed two cycle starts after frame ``mark`` of ``life`` (or of a new
        life since): the action's effects are over before the next one begins."""
        def settled() -> bool:
            done = self.frames_processed()
            start = 0 if life is not self.ledger.open_life else mark
            current = self.ledger.open_life
            return current is not None and sum(1 for t in current.transitions if start <= t.index < done) >= 2
        wait_for(settled, SETTLE_TIMEOUT_S, "the agent to process two cycles after the action", tick=self.tick)

    def frames_processed(self) -> int:
        """Frames the open agent life has reported processed."""
        if self.health is None or not self.lives:
            return 0
        record = self.health.latest(self.lives[-1].started)
        return int(record.get("frames_total", 0)) if record else 0

    # -- the loop ---------------------------------------------------------------------------
    def idle(self, seconds: float) -> None:
        end = time.monotonic() + seconds
        while time.monotonic() < end:
            self.tick()
            time.sleep(min(0.2, max(end - time.monotonic(), 0.0)))

    def tick(self) -> None:
        """Periodic work: account for the link, the status line (the RSS sampler has its own thread)."""
        self.tap.pump()
        now = time.monotonic()
        if now - self._last_status >= STATUS_EVERY_S:
            self._last_status = now
            log.info(self.status_line())
            write_samples(self.lives, self.work / "resources.csv")     # so far: an interrupted soak leaves it

    def sample(self, force: bool = False) -> None:
        """One RSS/CPU sample of the open agent life, if one is due (or ``force``)."""
        with self._sample_lock:
            now = time.monotonic()
            agent, life = self.agent, self.lives[-1] if self.lives else None
            if agent is None or life is None or agent.pid != life.pid or (
                    not force and now - self._last_sample < self.args.sample_interval):
                return
            self._last_sample = now
            got = proc_cpu_rss(agent.pid)
            if got is not None:
                life.samples.append(Sample(time.time(), got[1], got[0]))

    def _sample_loop(self) -> None:
        """The sampler thread: a loop of its own, so that nothing the main loop waits for can starve it."""
        while not self._sampler_stop.wait(min(self.args.sample_interval / 4.0, 0.5)):
            try:
                self.sample()
            except Exception:                              # noqa: BLE001 - a sampler must not die silently
                log.exception("RSS sampler")

    def _stop_sampler(self) -> None:
        self._sampler_stop.set()
        if self._sampler.is_alive():
            self._sampler.join(timeout=5.0)

    def status_line(self) -> str:
        elapsed = time.monotonic() - self.stream_started if self.stream_started else 0.0
        in_file, got = (self._lines[name].count() for name in ("symptoms.jsonl", "received.jsonl"))
        return (f"status: {elapsed:.0f}/{self.args.duration:.0f} s, frames on link {sum(r.frames for r in self.ledger.runs)}, "
                f"processed {self.frames_processed()} (agent life {len(self.lives) - 1}), symptoms JSONL "
                f"{in_file} / subscriber {got} lines, restarts {sum(self.counts.restarts.values())}")

    def run(self) -> dict[str, Any]:
        self.start_router()
        self.health = HealthWatch(self.endpoint)
        self.start_subscriber()
        self.start_agent()
        self._sampler.start()
        self.start_sim()
        self.stream_started = time.monotonic()
        plan = [] if self.args.no_chaos else chaos_plan(self.args.duration, self.args.chaos_interval, self.args.seed)
        log.info("%s; router %s; chaos %s", self.link_text, self.endpoint,
                 ", ".join(f"{kind}@{t:.0f}s" for t, kind in plan) or "off")
        while plan or time.monotonic() - self.stream_started < self.args.duration:
            self.check_processes()
            if plan and time.monotonic() - self.stream_started >= plan[0][0]:
                self.chaos(plan.pop(0)[1])
            self.idle(0.5)
        wall = time.monotonic() - self.stream_started
        self.finish()
        return self.report(wall)

    def check_processes(self) -> None:
        for proc in (self.sim, self.agent, self.router, self.subscriber):
            if proc is not None and not proc.alive():
                raise RuntimeError(f"{proc.name} exited unexpectedly (code {proc.popen.returncode}); "
                                   f"see {proc.stderr}")

    def finish(self) -> None:
        """Stop in order: simulator, let the agent drain, let the subscriber catch up, agent, subscriber."""
        self.stop_sim()
        wait_for(self.drained, SETTLE_TIMEOUT_S, "the agent to process every frame", tick=self.tick)
        wait_for(self.subscriber_caught_up, 60.0, "the subscriber to receive what the JSONL file holds",
                 tick=self.tick)
        self.stop_agent()
        assert self.subscriber is not None
        self.subscriber.stop(signal.SIGTERM, timeout=30.0)

    def drained(self) -> bool:
        life = self.ledger.open_life
        assert self.health is not None
        record = self.health.latest(self.lives[-1].started)
        if life is None or record is None:
            return False
        taken = record.get("frames_total", 0) + record.get("queue_dropped", 0)
        return record.get("queue_depth", 1) == 0 and taken >= life.read

    def subscriber_caught_up(self) -> bool:
        in_file, _, _ = read_symptom_lines(self.work / "symptoms.jsonl", ROBOT)
        got, _, _ = read_symptom_lines(self.work / "received.jsonl", ROBOT)
        return set(in_file) <= set(got)

    # -- the result -------------------------------------------------------------------------
    def report(self, wall: float) -> dict[str, Any]:
        assert self.health is not None
        for life in self.lives:
            if life.killed:
                life.counters = self.health.latest(life.started, life.ended) or {}
        self.tap.pump()
        out: dict[str, Any] = {"link": self.link_text, "duration_s": round(wall, 1)}
        out.update(frame_report(self.ledger, self.lives, self.sims))
        out.update(fault_report(self.ledger, self.lives, self.sims))
        out.update(resource_report(self.lives, wall, self.args.warmup, self.args.slope_last))
        write_samples(self.lives, self.work / "resources.csv")
        out.update(symptom_report(self.ledger, self.lives, self.sims, self.args.joints,
                                  self.work / "symptoms.jsonl", self.work / "received.jsonl", ROBOT))
        out["restarts"] = {**self.counts.restarts, "total": sum(self.counts.restarts.values())}
        out.update({"chaos": self.counts.chaos_log, "agent_lives": len(self.lives), "simulator_runs": len(self.sims),
                    "link_malformed_lines": self.tap.malformed,
                    "symptoms_republished": sum(life.get("symptoms_republished") for life in self.lives),
                    "work_dir": str(self.work) if self.args.keep else None})
        out["ok"] = rules_hold(out)
        return out


def rules_hold(r: dict[str, Any]) -> bool:
    """Every reconciliation rule of docs/RELIABILITY.md holds."""
    return (r["frames_unaccounted"] == 0 and r["faults_detected"] == r["faults_detectable"]
            and r["faults_on_link"] == r["faults_injected"] and r["cycles_lost"] == 0
            and r["symptoms_received"] == r["symptoms_expected"] and r["symptoms_unexpected"] == 0
            and r["symptoms_unmapped"] == 0 and r["cycle_time_mismatches"] == 0
            and r["symptoms_expected_marked_partial"] == 0)


def _interrupt(_signum: int, _frame: Any) -> None:
    raise KeyboardInterrupt


def clear_work(work: Path) -> None:
    """Remove what an earlier soak left in ``work`` (a fresh agent state is part of the rules)."""
    for pattern in ("*.jsonl", "*.jsonl.*", "*.out", "*.log", "*.params.json", "resources.csv", "state/*"):
        for path in work.glob(pattern):
            path.unlink()


def main(argv: list[str] | None = None) -> int:
    args = parse_args(argv)
    logging.basicConfig(level=logging.DEBUG if args.verbose else logging.INFO, stream=sys.stderr,
                        format="%(asctime)s %(name)s: %(message)s")
    for signum in (signal.SIGINT, signal.SIGTERM):      # also when started with SIGINT ignored
        signal.signal(signum, _interrupt)
    with contextlib.ExitStack() as stack:
        if args.keep:
            work = Path(args.keep)
            work.mkdir(parents=True, exist_ok=True)
            clear_work(work)
        else:
            work = Path(stack.enter_context(tempfile.TemporaryDirectory(prefix="soak-")))
        try:
            result = Soak(args, work, stack).run()
        except KeyboardInterrupt:
            log.warning("interrupted: stopping every process")
            return 130
        except RuntimeError as exc:
            log.error("soak failed: %s", exc)
            return 1
    if args.json:
        print(json.dumps(result, indent=2))
    else:
        for key, value in result.items():
            print(f"{key:32} {value}")
    return 0 if result["ok"] else 1


if __name__ == "__main__":
    sys.exit(main())
