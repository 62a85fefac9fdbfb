#!/usr/bin/env python3
"""Benchmark: latency from the last frame of a cycle on the link to the symptom at an independent
Zenoh subscriber (goal p99 ≤ 100 ms), at the default robot's rate (6 joints × 500 Hz ≈ 3,000 frames/s).

Runs the processes of tools/bench/bench_live.py (simulator, pty slcan link, agent, Zenoh router, a
subscriber process) for ``--cycles`` complete test cycles (default 35) and writes
docs/benchmarks/latency.md. Definition, clock and method: see :mod:`bench_live` and the doc.

    .venv/bin/python tools/bench/bench_latency.py [--cycles 35] [--fps 3000]
"""

from __future__ import annotations

import argparse
import logging
import math
import sys
from pathlib import Path

sys.path[:0] = [str(Path(__file__).resolve().parents[2]), str(Path(__file__).resolve().parent),
                 str(Path(__file__).resolve().parents[1] / "soak")]     # bench_live takes the soak's link tap

import bench_live  # noqa: E402
from benchmark_report import write_report  # noqa: E402

log = logging.getLogger("bench_latency")


def markdown(result: dict, cycles: int, cmd: str) -> str:
    lat = result["latency_s"]
    ok = math.isfinite(lat["p99"]) and lat["p99"] <= 0.100
    lines = [
        "## Latency: end of a cycle on the link → symptom at a subscriber (`tools/bench/bench_latency.py`)", "",
        "Definition. For each test cycle c and joint j: t₀ = the moment the pty bridge queued the last frame of "
        "cycle c for the agent's end of the slcan link (the frame just before the first ControllerStatus frame of "
        "cycle c + 1 — the agent cannot know earlier that the cycle ended); t₁ = the moment an independent "
        "subscriber process (Zenoh client of the router, the agent's own advanced subscriber) received the "
        "symptom record of (j, c). Latency = t₁ − t₀. Both stamps are `time.monotonic()` (CLOCK_MONOTONIC), taken "
        "in two processes of the same host, where it is one clock. The path: pty → python-can slcan reader "
        "thread → bounded queue → processing thread (frames gathered up to 30 ms per block, "
        "`LiveSource.batch_s`) → cycle close: wear estimation, KDE/KL, GLR for every joint → JSONL + Zenoh "
        "publisher → router (TCP on 127.0.0.1) → subscriber.", "",
        f"Setup: {bench_live.JOINTS} joints at 500 Hz, test cycle speeds "
        f"{', '.join(map(str, bench_live.SPEEDS))} rad/s (cycle {result['cycle_s']:.1f} s simulated), paced to "
        f"{result['fps_target']:,.0f} frames/s ({result['fps_achieved']:,.0f} achieved), "
        f"{result['duration_s']:.0f} s, no link faults. {bench_live.machine_line(cmd)}", "",
        "| symptoms | cycles | p50 | p90 | p99 | max |", "|---|---:|---:|---:|---:|---:|",
        f"| every (joint, cycle) | {lat['cycles']} | {lat['p50'] * 1e3:.0f} ms | {lat['p90'] * 1e3:.0f} ms | "
        f"{lat['p99'] * 1e3:.0f} ms | {lat['max'] * 1e3:.0f} ms |",
        f"| last joint of each cycle | {lat['cycles']} | {lat['last_p50'] * 1e3:.0f} ms | "
        f"{lat['last_p90'] * 1e3:.0f} ms | {lat['last_p99'] * 1e3:.0f} ms | {lat['last_max'] * 1e3:.0f} ms |",
        "",
        f"{lat['n']} symptoms. Goal p99 ≤ 100 ms: **{'met' if ok else 'NOT met'}**"
        + ("" if lat["cycles"] >= cycles else f" (only {lat['cycles']} complete cycles, {cycles} asked)") + ". "
        "Percentiles are nearest-rank. Frames lost in the run: "
        f"{result['frames_lost']}. The machine is shared: other jobs' load lengthens the cycle-close work "
        "(the load average is in the run line above).", "",
        "Slowest cycles: " + "; ".join(
            f"cycle {c['cycle']}: {c['latency_s'] * 1e3:.0f} ms ({', '.join(c['stages'])}"
            + (", a learning phase ended in this cycle" if c["stage_changed"] else "") + ")"
            for c in result.get("slowest_cycles", [])) + "."
        + (" At the end of a learning phase a joint fits its friction model (least squares) or calibrates its "
           "detectors, once per joint's lifetime; such cycles are the outliers when they are in the sample."
           if any(c["stage_changed"] for c in result.get("slowest_cycles", [])) else ""),
        "",
        "What the sample covers: the first cycles of a fresh agent — each joint learns its friction model "
        "for 20 cycles, then wear estimation and KDE/KL run every cycle while the GLR detectors learn their "
        "nominal (60 cycles); the GLR monitoring step (O(window) per cycle) is therefore not in this sample.",
        "",
        "The latency is sensitive to the load of the shared machine: an earlier run of the same command at a "
        "load average of ≈ 8 (2 cores) measured p50 43 ms but p99 456 ms (one cycle's symptoms delayed), "
        "before the run above at the load shown. The cycle-close work (wear fit, KDE/KL, GLR for 6 joints) "
        "runs on the processing thread; on a loaded host it competes for the CPU with everything else.", ""]
    return "\n".join(lines) + "\n"


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--cycles", type=int, default=35, help="complete test cycles to measure (default 35)")
    ap.add_argument("--fps", type=float, default=bench_live.NOMINAL_FPS)
    ap.add_argument("--keep", help="keep the work files here")
    ap.add_argument("--json", help="also write the raw result here")
    ap.add_argument("--out", default="docs/benchmarks/latency.md")
    args = ap.parse_args(argv)
    logging.basicConfig(level=logging.INFO, stream=sys.stderr, format="%(asctime)s %(name)s: %(message)s")
    cycle_s = bench_live.cycle_seconds(bench_live.JOINTS)
    speedup = args.fps / bench_live.frames_per_simulated_second(bench_live.JOINTS)
    duration = (args.cycles + 1.5) * cycle_s / speedup
    log.info("%d cycles of %.1f s at %.0f frames/s: %.0f s of streaming", args.cycles, cycle_s, args.fps, duration)
    result = bench_live.run_phase(args.fps, duration, warmup=10.0, keep=args.keep)
    result["cycle_s"] = cycle_s
    cmd = ".venv/bin/python tools/bench/bench_latency.py " + " ".join(sys.argv[1:] if argv is None else argv)
    write_report(markdown(result, args.cycles, cmd.strip()), args.out, args.json, result)
    return 0


if __name__ == "__main__":
    sys.exit(main())
