#!/usr/bin/env python3
"""Benchmark: the live agent over the pty slcan link — loss at bus saturation, CPU share, latency.

The processes of tools/soak/soak.py without chaos and without link faults: ``sim-controller run`` paced at
a given frame rate, ``edge-monitor run`` (JSONL, state dir, Zenoh client), a Zenoh router on a free
loopback port (multicast scouting off), and an independent subscriber (this script with
``--subscriber``) that stamps every symptom it receives with ``time.monotonic()``. The pty bridge
runs in this process (tools/soak/soak_link.py) and stamps, with the same clock, the moment it queued each
chunk of frames for the agent's end of the link — so every frame the agent reads has a time "on the
link". CLOCK_MONOTONIC is one clock for all processes of a Linux host, so the difference is a latency.

Phases (``--phase``):

* ``saturation``: 6 joints paced so that 9,009 frames/s (classical CAN at 1 Mbit/s, 8-byte frames)
  cross the link for ``--duration`` seconds (default 600); loss = frames sent − frames the agent
  counted, plus link overflow and queue drops, all from the soak's ledger (exact).
* ``rate``: 3,000 frames/s (``--fps``); the agent's CPU share over the steady part (after
  ``--warmup`` s): CPU seconds of its threads from /proc/PID/task/*/stat per wall second, with and
  without the link reader. python-can's Notifier thread (which runs pyserial's byte-by-byte slcan
  reads) has no OS thread name, so it is identified as the Python thread (same ``comm`` as the
  process, not the main thread) with the most CPU; the per-thread table is in the output.

Latency of a cycle (both phases): from the moment the bridge queued the last frame of cycle c for
the agent (the frame just before the first ControllerStatus of cycle c + 1, which is when the agent
can know the cycle ended) to the moment the independent subscriber received the symptom of (joint, c)
from the router. p50/p99 over every (joint, cycle) symptom of the complete cycles, and over the last
joint's symptom of each cycle.

    .venv/bin/python tools/bench/bench_live.py                       # saturation 600 s + CPU phase 60 s, writes live.md
    .venv/bin/python tools/bench/bench_live.py --duration 60 --cpu-duration 30 --out /tmp/live.md   # short
    .venv/bin/python tools/bench/bench_live.py --subscriber --connect tcp/127.0.0.1:PORT --out got.jsonl
"""

from __future__ import annotations

import argparse
import contextlib
import json
import logging
import math
import os
import platform
import subprocess
import sys
import tempfile
import time
from bisect import bisect_right
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

TOOLS = Path(__file__).resolve().parent
sys.path[:0] = [str(TOOLS.parents[1]), str(TOOLS), str(TOOLS.parent / "soak")]    # the soak's link tap

from benchmark_report import write_report  # noqa: E402

log = logging.getLogger("bench_live")

SATURATION_FPS = 9009.0          # 1 Mbit/s, 8-byte frames, 11-bit ids, no stuffing
NOMINAL_FPS = 3000.0
JOINTS = 6
SPEEDS = (8.7, 41.7)             # a 5.3 s test cycle at plateau 0.4 s (≈ 3.5 s of it production motion)
PLATEAU_TIME = 0.4


# -- the independent subscriber (a separate process) ------------------------------------------------------

def subscriber_main(args: argparse.Namespace) -> int:
    """The soak's subscriber (:func:`soak_subscriber.serve`) with two more fields per symptom: ``recv``,
    time.monotonic() on arrival, and the joint's ``stage``."""
    from soak_subscriber import serve

    return serve(args.connect, args.key, args.out, extra=lambda r, arrived: {"recv": arrived, "stage": stage(r)})


def stage(record: dict[str, Any]) -> str:
    """Where the joint's monitor is: "model learning" (empty wear section), "detector learning" (some
    decision still learning) or "monitoring"."""
    wear = record.get("wear") or {}
    if "score" not in wear:                     # the empty section: the joint's friction model is being learned
        return "model learning"
    decisions = record.get("decisions") or {}
    if not decisions or any((d or {}).get("state") != "monitoring" for d in decisions.values()):
        return "detector learning"
    return "monitoring"


def read_stages(path: Path) -> dict[tuple[int, int], str]:
    out: dict[tuple[int, int], str] = {}
    if path.exists():
        for line in path.read_text(errors="replace").splitlines():
            with contextlib.suppress(ValueError, KeyError, TypeError):
                r = json.loads(line)
                out.setdefault((int(r["joint"]), int(r["cycle"])), str(r.get("stage", "?")))
    return out


def slowest_cycles(ends: dict[int, float], received: dict[tuple[int, int], float],
                   stages: dict[tuple[int, int], str], n: int = 3) -> list[dict[str, Any]]:
    """The ``n`` cycles with the longest last-symptom latency, with the stages of their joints and
    whether a joint's stage changed in that cycle (the end of a learning phase)."""
    per: dict[int, float] = {}
    for (_joint, cycle), recv in received.items():
        if cycle in ends:
            per[cycle] = max(per.get(cycle, -math.inf), recv - ends[cycle])
    out = []
    for cycle in sorted(per, key=lambda c: -per[c])[:n]:
        here = {stages.get((j, cycle)) for (j, c) in received if c == cycle}
        changed = any(stages.get((j, cycle)) != stages.get((j, cycle - 1)) for (j, c) in received if c == cycle)
        out.append({"cycle": cycle, "latency_s": per[cycle], "stages": sorted(str(x) for x in here),
                    "stage_changed": changed})
    return out


# -- link times ------------------------------------------------------------------------------------------

def chunk_time(chunks: list[tuple[int, float]], frame_index: int) -> float | None:
    """Time of the chunk that brought frame ``frame_index`` (chunks: (frames read after it, time))."""
    ends = [c[0] for c in chunks]
    k = bisect_right(ends, frame_index)
    return chunks[k][1] if k < len(chunks) else None


def cycle_end_times(transitions: list[Any], chunks: list[tuple[int, float]], offsets: dict[int, int]
                    ) -> dict[int, float]:
    """Agent cycle number → time the last frame of that cycle was queued on the link. A cycle is
    closed by the first status frame of the next cycle of the same run (``transition.pred``)."""
    out: dict[int, float] = {}
    for t in transitions:
        pred = t.pred
        if pred is None or pred[0] not in offsets or t.key != (pred[0], pred[1] + 1):
            continue
        when = chunk_time(chunks, t.index - 1)
        if when is not None:
            out[pred[1] + offsets[pred[0]]] = when
    return out


def read_received(path: Path) -> dict[tuple[int, int], float]:
    """(joint, cycle) → first arrival time of a complete (not partial) symptom."""
    out: dict[tuple[int, int], float] = {}
    if not path.exists():
        return out
    for line in path.read_text(errors="replace").splitlines():
        try:
            r = json.loads(line)
        except ValueError:
            continue
        if "recv" not in r or r.get("partial") or r.get("joint") is None or r.get("cycle") is None:
            continue
        out.setdefault((int(r["joint"]), int(r["cycle"])), float(r["recv"]))
    return out


def latencies(ends: dict[int, float], received: dict[tuple[int, int], float]) -> tuple[list[float], list[float]]:
    """(latency of every (joint, cycle) symptom, latency of each cycle's last symptom) [s]."""
    every: list[float] = []
    last: dict[int, float] = {}
    for (_joint, cycle), recv in received.items():
        if cycle in ends:
            every.append(recv - ends[cycle])
            last[cycle] = max(last.get(cycle, -math.inf), recv - ends[cycle])
    return every, list(last.values())


def percentile(values: list[float], q: float) -> float:
    if not values:
        return math.nan
    s = sorted(values)
    k = min(len(s) - 1, max(0, math.ceil(q / 100.0 * len(s)) - 1))   # nearest rank
    return s[k]


def latency_summary(every: list[float], last: list[float]) -> dict[str, Any]:
    return {"n": len(every), "cycles": len(last),
            **{f"p{q}": percentile(every, q) for q in (50, 90, 99)}, "max": max(every) if every else math.nan,
            **{f"last_p{q}": percentile(last, q) for q in (50, 90, 99)},
            "last_max": max(last) if last else math.nan}


# -- per-thread CPU --------------------------------------------------------------------------------------

def thread_ticks(pid: int) -> dict[int, tuple[str, int]]:
    """tid → (comm, utime + stime ticks) of every thread of ``pid``."""
    out: dict[int, tuple[str, int]] = {}
    with contextlib.suppress(OSError):
        for entry in os.listdir(f"/proc/{pid}/task"):
            with contextlib.suppress(OSError, IndexError, ValueError):
                text = Path(f"/proc/{pid}/task/{entry}/stat").read_text()
                comm = text[text.index("(") + 1:text.rindex(")")]
                fields = text.rsplit(")", 1)[1].split()
                out[int(entry)] = (comm, int(fields[11]) + int(fields[12]))
    return out


@dataclass
class CpuWindow:
    """CPU per thread between two snapshots, classified."""

    wall_s: float
    threads: list[dict[str, Any]] = field(default_factory=list)

    @classmethod
    def between(cls, pid: int, a: tuple[float, dict[int, tuple[str, int]]],
                b: tuple[float, dict[int, tuple[str, int]]]) -> CpuWindow:
        hz = os.sysconf("SC_CLK_TCK")
        wall = b[0] - a[0]
        main_comm = b[1].get(pid, ("?", 0))[0]
        rows: list[dict[str, Any]] = []
        for tid, (comm, ticks) in b[1].items():
            used = (ticks - a[1].get(tid, (comm, 0))[1]) / hz
            kind = "main (processing)" if tid == pid else ("python" if comm == main_comm else f"native ({comm})")
            rows.append({"tid": tid, "comm": comm, "kind": kind, "cpu_s": used, "share": used / wall})
        python = [r for r in rows if r["kind"] == "python"]
        if python:
            reader = max(python, key=lambda r: float(r["cpu_s"]))
            reader["kind"] = "link reader (python-can Notifier, slcan)"
        return cls(wall, sorted(rows, key=lambda r: -r["cpu_s"]))

    @property
    def total(self) -> float:
        return sum(r["share"] for r in self.threads)

    @property
    def reader(self) -> float:
        return sum(r["share"] for r in self.threads if r["kind"].startswith("link reader"))


# -- the run ---------------------------------------------------------------------------------------------

def frames_per_simulated_second(joints: int) -> float:
    from sim_controller.config import SimConfig
    from sim_controller.controller import Controller

    probe = Controller(SimConfig(joints=joints, cycles=1, seed=1, speeds=SPEEDS, plateau_time=PLATEAU_TIME))
    frames = sum(len(b) for b in probe.frames())
    return frames / probe.simulated_seconds


def cycle_seconds(joints: int) -> float:
    from sim_controller.config import SimConfig
    from sim_controller.controller import Controller

    probe = Controller(SimConfig(joints=joints, cycles=2, seed=1, speeds=SPEEDS, plateau_time=PLATEAU_TIME))
    for _ in probe.frames():
        pass
    return probe.simulated_seconds / 2


def run_phase(fps: float, duration: float, warmup: float, keep: str | None, seed: int = 1,
              profile_s: float = 0.0) -> dict[str, Any]:
    """One soak without chaos or link faults at ``fps`` frames/s for ``duration`` s; loss, CPU, latency."""
    import soak
    from soak_link import PtyLinkTap

    from protocol.links import PtyPair

    class TimedTap(PtyLinkTap):
        """The soak's tap, with the time each chunk was queued for the agent (frames read after it)."""

        def __init__(self, *a: Any, **kw: Any) -> None:
            super().__init__(*a, **kw)
            self.chunks: dict[int, list[tuple[int, float]]] = {}

        def queued(self, end: str, data: bytes) -> None:
            if end == self.end:
                self._events.append(("queued_timed", data, time.monotonic()))

        def _on_queued_timed(self, data: bytes, when: float) -> None:
            self._on_queued(data)
            life = self.ledger.open_life
            if life is not None:
                self.chunks.setdefault(life.index, []).append((life.read, when))

    class LiveSoak(soak.Soak):
        def _open_link(self, link: str) -> tuple[Any, str, str, str]:
            pair = PtyPair(max_buffer=soak.LINK_BUFFER)
            tap = TimedTap(pair.b, self.ledger, window=soak.LINK_BUFFER + (1 << 20))
            pair.observer = tap
            self.stack.callback(pair.close)
            self.pair = pair
            return tap, f"slcan:{pair.a}", f"slcan:{pair.b}", f"slcan over pty {pair.a} <-> {pair.b}"

        def start_subscriber(self) -> None:
            proc = self.subscriber = soak.Proc("subscriber", [
                sys.executable, str(Path(__file__).resolve()), "--subscriber", "--connect", self.endpoint,
                "--key", f"edge/{soak.ROBOT}/*/symptom", "--out", str(self.work / "received.jsonl")], self.work)
            if not soak.wait_for(lambda: "subscriber ready" in proc.output(), soak.START_TIMEOUT_S, "the subscriber"):
                raise RuntimeError("the subscriber did not start (see subscriber.log)")

        threads: list[tuple[float, dict[int, tuple[str, int]]]] = []

        def sample(self, force: bool = False) -> None:
            due = force or time.monotonic() - self._last_sample >= self.args.sample_interval
            super().sample(force)
            if due and self.agent is not None and self.stream_started:
                self.threads.append((time.monotonic(), thread_ticks(self.agent.pid)))

        def finish(self) -> None:
            self.sample(force=True)
            self.streaming_ended = time.monotonic()
            super().finish()

    if profile_s:                        # the agent under py-spy (it cannot attach to a running process here)
        spy = str(Path(sys.executable).with_name("py-spy"))
        plain_proc = soak.Proc

        class ProfiledProc(plain_proc):  # type: ignore[misc,valid-type]
            def __init__(self, name: str, cmd: list[str], work: Path) -> None:
                if name.startswith("agent"):
                    cmd = [spy, "record", "-r", "100", "--threads", "--duration", str(int(profile_s)), "--format",
                           "raw", "-o", str(work / f"{name}.pyspy.txt"), "--", *cmd]
                super().__init__(name, cmd, work)

        soak.Proc = ProfiledProc  # type: ignore[misc]
    soak.SPEEDS, soak.PLATEAU_TIME = SPEEDS, PLATEAU_TIME  # type: ignore[assignment]
    soak.AGENT_CONFIG = (f'robot = "{soak.ROBOT}"\nstatus_interval_s = 1.0\n[segmentation]\n'
                         f'speeds = [{", ".join(str(v) for v in SPEEDS)}]\n')
    per_sim_s = frames_per_simulated_second(JOINTS)
    speedup = fps / per_sim_s
    args = soak.parse_args(["--duration", str(duration), "--joints", str(JOINTS), "--speedup", f"{speedup:.6f}",
                            "--faults", "", "--no-chaos", "--seed", str(seed), "--warmup", str(warmup)]
                           + (["--keep", keep] if keep else []))
    with contextlib.ExitStack() as stack:
        if keep:
            work = Path(keep)
            work.mkdir(parents=True, exist_ok=True)
            soak.clear_work(work)
        else:
            work = Path(stack.enter_context(tempfile.TemporaryDirectory(prefix="bench-live-")))
        s = LiveSoak(args, work, stack)
        s.threads = []
        report = s.run()
        tap = s.tap
        assert isinstance(tap, TimedTap)
        life = s.ledger.lives[0]
        ends = cycle_end_times(life.transitions, tap.chunks.get(life.index, []), s.ledger.numbering())
        received = read_received(work / "received.jsonl")
        every, last = latencies(ends, received)
        slow = slowest_cycles(ends, received, read_stages(work / "received.jsonl"))
        steady = [x for x in s.threads if x[0] - s.stream_started >= warmup and x[0] <= s.streaming_ended]
        agent_pid = s.agent.pid if s.agent is not None else 0
        cpu = CpuWindow.between(agent_pid, steady[0], steady[-1]) if len(steady) >= 2 else None
    # a send that raised (serial write timeout) may still have put its frame on the link, where the agent
    # counts it: that frame is on the link, not lost and not one too many (tools/soak/soak_report.py)
    loss = report["frames_sent"] + report["send_errors_on_link"] - report["frames_received"]
    return {
        "fps_target": fps, "speedup": speedup, "frames_per_simulated_s": per_sim_s,
        "duration_s": report["duration_s"], "frames_sent": report["frames_sent"],
        "frames_received": report["frames_received"], "frames_lost": loss,
        "send_errors": report["send_errors"], "send_errors_on_link": report["send_errors_on_link"],
        "frames_unaccounted": report["frames_unaccounted"], "frames_queue_dropped": report["frames_queue_dropped"],
        "link_overflow": report["frames_unaccounted_by_rule"]["link_overflow"],
        "fps_achieved": report["frames_sent"] / report["duration_s"] if report["duration_s"] else None,
        "symptoms_expected": report["symptoms_expected"], "symptoms_received": report["symptoms_received"],
        "soak_rules_hold": report["ok"], "agent_group_cpu_percent": report["cpu_percent"],
        "rss_mb_end": report["rss_mb_end"],
        "cpu": None if cpu is None else {"wall_s": cpu.wall_s, "total": cpu.total, "reader": cpu.reader,
                                         "without_reader": cpu.total - cpu.reader, "threads": cpu.threads},
        "latency_s": latency_summary(every, last), "slowest_cycles": slow,
        "load_average": os.getloadavg(),
    }


# -- report ----------------------------------------------------------------------------------------------

def machine_line(cmd: str) -> str:
    up = subprocess.run(["uptime"], capture_output=True, text=True).stdout.strip()
    return (f"Run: `{cmd}` on {platform.machine()} Linux, {os.cpu_count()} cores (shared with other jobs), "
            f"Python {platform.python_version()}, {time.strftime('%Y-%m-%d %H:%M UTC', time.gmtime())}; "
            f"`uptime` at the end: `{up}`.")


def cpu_table(cpu: dict[str, Any]) -> list[str]:
    lines = ["| thread | kind | CPU s | share of a core |", "|---|---|---:|---:|"]
    for r in cpu["threads"]:
        if r["cpu_s"] > 0:
            lines.append(f"| {r['tid']} `{r['comm']}` | {r['kind']} | {r['cpu_s']:.1f} | {r['share']:.1%} |")
    return lines


def latency_line(lat: dict[str, Any]) -> str:
    return (f"{lat['n']} symptoms of {lat['cycles']} complete cycles: p50 {lat['p50'] * 1e3:.0f} ms, "
            f"p99 {lat['p99'] * 1e3:.0f} ms, max {lat['max'] * 1e3:.0f} ms; last joint of each cycle: "
            f"p50 {lat['last_p50'] * 1e3:.0f} ms, p99 {lat['last_p99'] * 1e3:.0f} ms")


#: A re-check by hand (not the run above), kept with the figures.
RECHECK = ('Re-check after the subscriber refactoring (2026-11-23 ≈ 17:30 UTC, `tools/bench/bench_live.py --phase rate'
           ' --cpu-duration 30 --warmup 5`, other jobs on the machine): 24 s of steady streaming at 3,000 '
           'frames/s, the agent 11.9 % of a core without the link reader (reader 10.1 %, all threads 22.0 %), 0 '
           'frames lost, latency p50 22 ms, p99 47 ms (24 symptoms). A short window under load; the CPU goal '
           'stays not met. A/B on a quiet machine later that evening (2026-11-23 ≈ 19:55 UTC, `--phase rate '
           '--cpu-duration 60`, the two versions alternating, each from its own checkout): the code of that '
           're-check (dd08576) used 16.8, 17.4 and 17.4 % of a core without the link reader, the code with the '
           'span-only KDE binning and kl.min_speed = 10 (4455c5e and later) 16.0, 15.1, 15.2 and 15.6 %: 0.90× '
           'the CPU. No frame was lost; one run printed a loss of −1, the agent counting one frame more than the'
           " simulator's successful sends, which is what a send that raised yet reached the link does (not "
           'checked for that run); bench_live now counts such a frame as on the link, as the soak does. The '
           'machine gave both versions more than the earlier 10.2 % on the same command, so the absolute share '
           'varies from day to day here; the goal is not met on either.')


def markdown(sat: dict[str, Any] | None, rate: dict[str, Any] | None, cmd: str) -> str:
    lines = ["## Live agent over the pty slcan link (`tools/bench/bench_live.py`)", "",
             f"Processes as in the soak (tools/soak/soak.py), no chaos, no link faults: `sim-controller run` ({JOINTS} "
             f"joints at 500 Hz, test cycle speeds {', '.join(map(str, SPEEDS))} rad/s, paced to a frame rate), "
             "`edge-monitor run` (JSONL, state dir, Zenoh client), a Zenoh router on a loopback port, an "
             "independent subscriber; the pty bridge in the benchmark process counts every frame (exact ledger "
             "of tools/soak/soak_link.py). Loss = frames the simulator put on the link − frames the agent counted.", "",
             machine_line(cmd), ""]
    if sat is not None:
        ok = sat["frames_lost"] == 0 and sat["frames_unaccounted"] == 0 and sat["frames_queue_dropped"] == 0
        lines += [f"**Bus saturation** (goal: zero loss at 9,009 frames/s for 10 min): {sat['duration_s']:.0f} s at "
                  f"{sat['fps_achieved']:,.0f} frames/s on the link (target {sat['fps_target']:,.0f}): "
                  f"{sat['frames_sent']:,} frames sent, {sat['frames_received']:,} counted by the agent, "
                  f"**{sat['frames_lost']} lost** (link overflow {sat['link_overflow']}, agent queue drops "
                  f"{sat['frames_queue_dropped']}, unaccounted {sat['frames_unaccounted']}) — "
                  f"{'met' if ok else 'NOT met'}. Symptoms: {sat['symptoms_received']} of "
                  f"{sat['symptoms_expected']} expected received by the subscriber. Latency at saturation: "
                  f"{latency_line(sat['latency_s'])}. Load average during the run (1/5/15 min at the end): "
                  f"{' / '.join(f'{x:.1f}' for x in sat['load_average'])}.", ""]
        if sat.get("cpu"):
            lines += [f"Agent CPU at saturation: {sat['cpu']['total']:.0%} of a core in total, "
                      f"{sat['cpu']['without_reader']:.0%} without the link reader.", ""]
    if rate is not None and rate.get("cpu"):
        cpu = rate["cpu"]
        lines += [f"**CPU share at {rate['fps_target']:,.0f} frames/s** (goal ≤ 10 % of a core excluding the link "
                  f"reader): over {cpu['wall_s']:.0f} s of steady streaming the agent used "
                  f"**{cpu['without_reader']:.1%} of a core without the link reader** "
                  f"({'met' if cpu['without_reader'] <= 0.10 else 'NOT met'}); the reader thread "
                  f"{cpu['reader']:.1%}, all threads {cpu['total']:.1%}. Frames lost: {rate['frames_lost']}. "
                  f"Per thread (CPU seconds from /proc/PID/task/*/stat over the window):", ""]
        lines += cpu_table(cpu)
        lines += ["", f"Latency in this run: {latency_line(rate['latency_s'])}.", ""]
    lines += ["Contention: a load average above 2 means other jobs competed for the 2 cores during the run. Loss "
              "does not depend on it as long as the agent keeps up (bounded queue, every drop counted), but CPU "
              "seconds per thread and the latency tail grow with it. The CPU share depends on how frames are "
              "gathered into blocks (`LiveSource.batch_s`, 30 ms): with blocks of a few frames the processing "
              "thread used ≈ 48 % of a core at 3,000 frames/s, with 20 ms ≈ 11 %, with 50 ms ≈ 5.5 % (short runs "
              "of this script at load ≈ 8–10); the agent's cost per block is mostly fixed, which is also why its "
              "share barely grows from 3,000 to 9,009 frames/s.", "",
              "The link reader is python-can's slcan bus (pyserial reads the pty byte by byte in the Notifier "
              "thread); it is the price of the portable link, not of the agent's work, and is absent on "
              "SocketCAN, where the kernel delivers whole frames.", "", RECHECK, ""]
    return "\n".join(lines) + "\n"


def parse_args(argv: list[str] | None = None) -> argparse.Namespace:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--subscriber", action="store_true", help="run as the independent subscriber process")
    ap.add_argument("--connect", help="--subscriber: router endpoint")
    ap.add_argument("--key", default="edge/**", help="--subscriber: key expression")
    ap.add_argument("--phase", choices=("saturation", "rate", "both"), default="both")
    ap.add_argument("--duration", type=float, default=600.0, help="seconds at saturation (default 600 = 10 min)")
    ap.add_argument("--cpu-duration", type=float, default=60.0, help="seconds of the CPU phase (default 60)")
    ap.add_argument("--fps", type=float, default=NOMINAL_FPS, help="frame rate of the CPU phase (default 3000)")
    ap.add_argument("--warmup", type=float, default=15.0, help="seconds left out of the CPU window")
    ap.add_argument("--keep", help="keep the work files of the last phase here")
    ap.add_argument("--profile-agent", type=float, default=0.0, metavar="S",
                    help="run the agent under py-spy for its first S seconds (AGENT.pyspy.txt in --keep); "
                         "the CPU figures then include py-spy")
    ap.add_argument("--json", help="also write the raw results here")
    ap.add_argument("--out", default="docs/benchmarks/live.md")
    args = ap.parse_args(argv)
    args.argv = list(sys.argv[1:] if argv is None else argv)
    return args


def main(argv: list[str] | None = None) -> int:
    args = parse_args(argv)
    if args.subscriber:
        if not args.connect or not args.out:
            raise SystemExit("--subscriber needs --connect and --out")
        logging.basicConfig(level=logging.WARNING)
        return subscriber_main(args)
    logging.basicConfig(level=logging.INFO, stream=sys.stderr, format="%(asctime)s %(name)s: %(message)s")
    rate = sat = None
    if args.phase in ("rate", "both"):
        log.info("CPU phase: %.0f frames/s for %.0f s", args.fps, args.cpu_duration)
        rate = run_phase(args.fps, args.cpu_duration, args.warmup, args.keep, profile_s=args.profile_agent)
    if args.phase in ("saturation", "both"):
        log.info("saturation phase: %.0f frames/s for %.0f s", SATURATION_FPS, args.duration)
        sat = run_phase(SATURATION_FPS, args.duration, args.warmup, args.keep)
    shown = [a for k, a in enumerate(args.argv) if a != "--json" and (k == 0 or args.argv[k - 1] != "--json")]
    cmd = ".venv/bin/python tools/bench/bench_live.py " + " ".join(shown)
    write_report(markdown(sat, rate, cmd.strip()), args.out, args.json, {"saturation": sat, "rate": rate})
    return 0


if __name__ == "__main__":
    sys.exit(main())
