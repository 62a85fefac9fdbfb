#!/usr/bin/env python3
"""Benchmark: agent replay throughput against merely iterating python-can's LogReader.

Records a simulated log (6 joints at 500 Hz by default) into a temporary .blf (and .log), then:

* whole processes, alternating, same run (issue #15 goal: full replay ≥ 0.7× the LogReader rate):
  ``python -c "for _ in can.LogReader(FILE)"`` against ``edge-monitor replay FILE --jsonl OUT --json``
  (decode, E2E, all detectors with the shipped config, JSONL sink), each timed from spawn to exit;
* in one process, alternating: (a) iterating ``can.LogReader``, (b) the replay path with ingest +
  segmentation + friction extraction only, (c) the full agent (wear estimation, KDE/KL, GLR), with
  the ratios b/a and c/a, plus the per-cycle, per-joint wear-estimation time;
* with ``--profile`` (default on when py-spy is installed): py-spy samples one full replay process
  and the table splits its time into start-up (imports), reading the log, the agent and the rest.

Writes docs/benchmarks/agent.md.

    .venv/bin/python tools/bench/bench_agent.py [--cycles 10] [--joints 6] [--repeats 3] [--no-profile]
"""

from __future__ import annotations

import argparse
import collections
import dataclasses
import os
import platform
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import can
import numpy as np
from benchmark_report import write_report

from edge_monitor.config import AgentConfig, DecisionConfig, KLConfig, WearConfig
from edge_monitor.features.wear_estimation import WearEstimator
from edge_monitor.pipeline.agent import Agent
from edge_monitor.sources.log_source import log_blocks
from sim_controller.config import SimConfig
from sim_controller.output import record

PROFILE_NOTE = (
    "Before issue #15 the full replay ran at 0.46–0.61× the LogReader rate. py-spy showed why: of a replay "
    "process, python-can's `BLFReader` (one `struct.unpack` and one `can.Message` per frame, then "
    "`messages_to_arrays` back to arrays) took ≈ 40 %, start-up imports (scipy.optimize/signal/stats for "
    "the wear fit, KDE and GLR) ≈ 33 %, the agent itself (`Agent.update`) only ≈ 11 %. `.blf` files are now "
    "read a container at a time (`edge_monitor/sources/blf_blocks.py`): every 48-byte stride of a "
    "decompressed container is checked at once with numpy and runs of CAN_MESSAGE objects become frame "
    "arrays directly, bit-identical to python-can's messages (tests/test_blf_blocks.py compares both paths "
    "on simulator logs, python-can-written logs with extended/remote/short/error frames, cut and damaged "
    "files); anything else goes through python-can's own parser. The golden replay tests are unchanged. "
    "Text logs (`.log`, `.asc`) are still read by python-can one message at a time, so their replay "
    "stays below the LogReader rate (the rows above); a vectorised candump reader is the next step if that "
    "matters. The start-up cost (imports of scipy.optimize/signal/stats, numpy, python-can, zenoh; the first row of the profile) is fixed per process: it weighs on short files only, and is a candidate for lazy imports.")


#: A measurement by hand (not reproduced by this script: ≈ 8 min), kept with the figures above.
USER_RUN = """A user's whole run at the defaults (2026-11-23 14:33 UTC, this machine, 2 cores, a CI run beside it):
`sim-controller record --cycles 200 --out big.blf` wrote 22,910,626 frames (6 joints, 6,839 s
simulated) in 14.8 s, 462× real time; `edge-monitor replay big.blf --json` took 286.6 s wall,
79,953 frames/s, including the inline threshold calibration of 24 detectors at the end of learning
(the bench above leaves that out); 200 cycles, 1,200 symptoms, none partial, no alarm. (Earlier the
same day, before the vectorised `.blf` reader: 427× and 53,074 frames/s.) Re-run at 17:34 UTC on the
final code, again beside a CI run: record 17.7 s (386× real time, peak RSS 135 MB); replay 312.1 s,
73,404 frames/s, peak RSS 159 MB; 200 cycles, 1,200 symptoms, **no alarm**. Again at 20:47 UTC on the code of bf10d33 (`kl.min_speed` = 10, span-only KDE binning), beside a full CI run: record 25.1 s (272× real time, peak RSS 134 MB); replay 559.1 s, 40,977 frames/s, peak RSS 159 MB; 200 cycles, 1,200 symptoms, **no alarm**. The slower figures follow the machine, which also ran the test suite 1.5× slower today than last session. Again at 23:57 UTC on the code of 08d572b (the faster calibration), beside test runs and, at its end, a CI run: record 22.0 s (311× real time); replay 333.5 s, 68,696 frames/s; 22,910,626 frames all OK, 200 cycles, 1,200 symptoms, **no alarm**. Again on 2026-11-24 at 02:43 UTC on the code of 1e4870f (the per-joint prior), beside a CI run: record 23.6 s (289× real time, peak RSS 134 MB); replay 300.6 s, 76,218 frames/s, peak RSS 159 MB; 22,910,626 frames all OK, 200 cycles, 1,200 symptoms, **no alarm**. Again on 2026-11-24 at 05:45 UTC on the code of 38754f8 (the per-joint sample gathering and the block-invariant segmentation), beside a CI run: record 21.9 s (312× real time, peak RSS 134 MB); replay 286.4 s, 79,998 frames/s, peak RSS 159 MB; 22,910,626 frames all OK, 200 cycles, 1,200 symptoms, **no alarm**. Again on 2026-11-24 at 09:20 UTC on the code of 51edfdc (the two detector stages), beside a CI run: record 22.0 s (311× real time, peak RSS 135 MB); replay 295.6 s, 78,083 frames/s, peak RSS 159 MB; 22,910,626 frames all OK, 200 cycles, 1,200 symptoms, **no alarm** (200 cycles end before any joint settles, so the run is all warm-up stage). The two-stage studies on the same code, alone on the machine: `tools/studies/arl_study.py --agent --quick` 3.0 min (2 processes; the fast path 132 s of it); `tools/studies/healthy_fleet_study.py --cycles 900 --seeds 0` 7.8 min; `tools/studies/arl_study.py --agent --targets 10000 --robots 2 --cycles 1400` 19 min beside other runs. On the code of c8c017a (the steady stage's Yeo–Johnson transform), 2026-11-24: `tools/studies/arl_study.py --agent --quick` 3.5 min (now 1 200 cycles); `tools/studies/healthy_fleet_study.py --cycles 900 --seeds 0` 8.4 min beside other runs; `tools/studies/arl_study.py --agent --targets 10000 --robots 2 --cycles 1400` 12.2 min. On the code of c94ee0d (the steady calibration from the values, thresholds for the fleet's rate), 2026-11-24: `tools/studies/arl_study.py --agent --quick` 4.0 min alone (now the agent's 48 draws, was 16); `tools/studies/healthy_fleet_study.py --cycles 200 --seeds 0 1 2` 8.3 min and `--cycles 800 --seeds 3 --joints 2` 6.9 min beside a CI run; `tools/studies/arl_study.py --agent --targets 10000 --robots 2 --cycles 1400` 19.7 min beside a CI run and other studies; a calibration simulates the same 48 detectors as before (12 learned nominals × 4 instead of 48 × 1), warm-up ones 2.9–4.2 s CPU each. Again on 2026-11-24 at 16:19 UTC on the code of b3540da (steady calibration from the values, fleet-rate thresholds), beside a CI run: record 22.6 s (303× real time); replay 246.2 s, 93,061 frames/s; 22,910,626 frames all OK, 200 cycles, 1,200 symptoms, **no alarm**."""

CALIBRATION_GAP = (
    "**Gap: the inline threshold calibration.** The files above (10 cycles) end before the detectors' "
    "learning does (20 cycles of model learning + 60 of detector learning), so they contain no threshold "
    "calibration. A replay of a file that reaches the end of learning calibrates every detector inline, "
    "once, which then dominates. Measured by hand after this change (2026-11-23 13:33 UTC, same machine, "
    "load ≈ 3–5): the default 200-cycle recording (22,910,626 frames) took 106.7 s to iterate with "
    "`can.LogReader` in its own process and 349.4 s to replay with `edge-monitor replay --jsonl --json` "
    "(65,803 frames/s, 0.31× the LogReader rate; 53,074 frames/s before the vectorised `.blf` reader); at "
    "the per-frame rate above the frames take ≈ 100 s of it, the inline calibration of the 24 detectors "
    "the remaining ≈ 4 min. Live, calibration runs in a worker process and costs no frames. So the ≥ 0.7× "
    "goal is met for the frame path (decode, E2E, features, detectors, JSONL) and not for a replay that "
    "includes the one-off calibration; cutting that is the calibration section's open item.")


def time_logreader(path: Path) -> tuple[float, int]:
    t = time.perf_counter()
    n = sum(1 for _ in can.LogReader(str(path)))
    return time.perf_counter() - t, n


def time_replay(path: Path, cfg: AgentConfig) -> tuple[float, int]:
    agent = Agent(cfg)
    t = time.perf_counter()
    for block in log_blocks(path, cfg.block_size):
        agent.update(*block)
    agent.finish()
    return time.perf_counter() - t, agent.stats.symptoms


READ_ONLY = "import can, sys; n = sum(1 for _ in can.LogReader(sys.argv[1])); print(n)"


def time_process(cmd: list[str]) -> float:
    """Wall seconds of one process from spawn to exit (output discarded; a failure raises)."""
    t = time.perf_counter()
    subprocess.run(cmd, check=True, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    return time.perf_counter() - t


def replay_cmd(path: Path, jsonl: Path) -> list[str]:
    return [sys.executable, "-m", "edge_monitor.cli", "replay", str(path), "--jsonl", str(jsonl), "--json", "-q"]


def whole_processes(path: Path, tmp: Path, repeats: int) -> tuple[float, float]:
    """Median wall seconds of (LogReader-iterating process, full replay process), alternating."""
    reads, replays = [], []
    for i in range(repeats):
        reads.append(time_process([sys.executable, "-c", READ_ONLY, str(path)]))
        jsonl = tmp / "replay.jsonl"
        jsonl.unlink(missing_ok=True)
        replays.append(time_process(replay_cmd(path, jsonl)))
        print(f"  {path.suffix} processes {i + 1}/{repeats}: LogReader {reads[-1]:.2f} s, replay {replays[-1]:.2f} s",
              file=sys.stderr, flush=True)
    return statistics.median(reads), statistics.median(replays)


#: py-spy frames (function (file)) that mark where a sample's time went, checked in this order.
BUCKETS = (
    ("start-up: imports and argument parsing", ("_find_and_load", "build_parser")),
    ("reading the log (edge_monitor/sources/log_source.py, blf_blocks.py, python-can)", ("_blocks (",)),
    ("the agent: decode, E2E, cycles, features, detectors, JSONL (Agent.update / finish)",
     ("Agent.update (", "Agent.finish (")),
)


def profile(path: Path, tmp: Path) -> tuple[list[tuple[str, float]], list[tuple[str, float]], int] | None:
    """py-spy samples of one replay process: (time per bucket, hottest functions by own time, samples)."""
    spy = shutil.which("py-spy") or str(Path(sys.executable).with_name("py-spy"))
    if not Path(spy).exists():
        return None
    raw = tmp / "profile.txt"
    jsonl = tmp / "profile.jsonl"
    result = subprocess.run([spy, "record", "-r", "250", "--format", "raw", "-o", str(raw), "--",
                             *replay_cmd(path, jsonl)], stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
    if result.returncode != 0 or not raw.exists():
        print(f"py-spy failed ({result.stderr.strip()[-200:]}); no profile", file=sys.stderr)
        return None
    buckets: collections.Counter[str] = collections.Counter()
    own: collections.Counter[str] = collections.Counter()
    total = 0
    for line in raw.read_text().splitlines():
        stack, _, count = line.rpartition(" ")
        n = int(count)
        total += n
        frames = stack.split(";")
        own[frames[-1].split(" (")[0] + " (" + frames[-1].split(" (")[-1].split(":")[0].split("/")[-1] + ")"] += n
        for name, marks in BUCKETS:
            if any(mark in frame for frame in frames for mark in marks):
                buckets[name] += n
                break
        else:
            buckets["other (interpreter start, shutdown, summary)"] += n
    shares = [(name, buckets[name] / total) for name, _ in BUCKETS] + \
        [("other (interpreter start, shutdown, summary)", buckets["other (interpreter start, shutdown, summary)"] / total)]
    return shares, [(f, n / total) for f, n in own.most_common(10)], total


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--cycles", type=int, default=10)
    ap.add_argument("--joints", type=int, default=6)
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--out", default="docs/benchmarks/agent.md")
    ap.add_argument("--no-profile", action="store_true", help="skip the py-spy profile")
    args = ap.parse_args()

    base = AgentConfig(kl=KLConfig(n_nominal_cycles=2), decision=DecisionConfig(n_nominal=5, density="gauss"))
    extraction_only = dataclasses.replace(base, wear=WearConfig(enabled=False), kl=KLConfig(enabled=False),
                                          decision=DecisionConfig(enabled=False))
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "bench.blf"
        summary = record(SimConfig(joints=args.joints, cycles=args.cycles, seed=3), path)
        frames = summary.frames_sent
        print(f"recorded {frames} frames ({args.joints} joints, {args.cycles} cycles, "
              f"{summary.simulated_s:.0f} simulated s) in {summary.wall_s:.2f} s", file=sys.stderr)
        print("whole processes ...", file=sys.stderr, flush=True)
        proc_blf = whole_processes(path, Path(tmp), args.repeats)
        log_path = Path(tmp) / "bench.log"
        record(SimConfig(joints=args.joints, cycles=args.cycles, seed=3), log_path)
        proc_log = whole_processes(log_path, Path(tmp), args.repeats)
        prof = None if args.no_profile else profile(path, Path(tmp))
        t_read, t_extract, t_full = [], [], []
        for i in range(args.repeats):
            t_read.append(time_logreader(path)[0])
            t_extract.append(time_replay(path, extraction_only)[0])
            t_full.append(time_replay(path, base)[0])
            print(f"repeat {i + 1}/{args.repeats}: read {t_read[-1]:.2f} s, extraction {t_extract[-1]:.2f} s, "
                  f"full {t_full[-1]:.2f} s", file=sys.stderr)
    read, extract, full = (statistics.median(x) for x in (t_read, t_extract, t_full))
    est = WearEstimator(method="marginal")      # as the agent uses it
    speeds = np.array([2.1, 8.7, 15.3, 21.9, 28.5, 35.1, 41.7, 82.2, 133.5, 184.7, 236.2, 287.1])
    from joint_model.friction import friction_magnitude
    tau = friction_magnitude(speeds, 0.5, 40.0, 20.0) + np.random.default_rng(0).normal(0, 5.7e-3, speeds.size)
    t = time.perf_counter()
    for _ in range(20):
        est.estimate(speeds, tau, 0.5, 0.1)
    per_estimate_ms = (time.perf_counter() - t) / 20 * 1e3

    procs = [
        ("`.blf`: `python -c 'for _ in can.LogReader(FILE)'` (baseline)", frames / proc_blf[0], 1.0),
        ("`.blf`: `edge-monitor replay FILE --jsonl OUT --json` (full agent)", frames / proc_blf[1],
         proc_blf[0] / proc_blf[1]),
        ("`.log` (candump): LogReader process (baseline)", frames / proc_log[0], 1.0),
        ("`.log` (candump): `edge-monitor replay` process (full agent)", frames / proc_log[1],
         proc_log[0] / proc_log[1]),
    ]
    rows = [
        ("LogReader iteration only (baseline)", frames / read, 1.0),
        ("replay: ingest + segmentation + extraction", frames / extract, read / extract),
        ("replay: full agent (wear, KDE/KL, GLR)", frames / full, read / full),
    ]
    lines = ["## Agent replay throughput (`tools/bench/bench_agent.py`)", "",
             f"{frames:,} frames of a simulated {args.joints}-joint robot at 500 Hz ({args.cycles} cycles), "
             f"recorded to `.blf` and to candump `.log`. Run: `.venv/bin/python tools/bench/bench_agent.py --cycles "
             f"{args.cycles} --repeats {args.repeats}` on {platform.machine()} Linux, {os.cpu_count()} cores "
             f"(shared; load average {os.getloadavg()[0]:.1f} at the end), Python {platform.python_version()}, "
             f"python-can {can.__version__}, {time.strftime('%Y-%m-%d %H:%M UTC', time.gmtime())}.", "",
             f"**Whole processes** (issue #15 goal: full replay ≥ 0.7× the LogReader rate on the same `.blf`), "
             f"each timed from spawn to exit (imports included), median of {args.repeats} alternating runs:", "",
             "| process | frames/s | rate ÷ LogReader rate |", "|---|---:|---:|"]
    lines += [f"| {name} | {rate:,.0f} | {ratio:.2f} |" for name, rate, ratio in procs]
    lines += ["", f"**In one process** (no start-up), median of {args.repeats} alternating runs on the `.blf`:", "",
              "| path | frames/s | rate ÷ LogReader rate |", "|---|---:|---:|"]
    lines += [f"| {name} | {rate:,.0f} | {ratio:.2f} |" for name, rate, ratio in rows]
    lines += ["", f"Wear estimation (12 speeds, temperature-marginalised likelihood as in the agent): {per_estimate_ms:.1f} ms per joint and cycle "
                  f"(target ≤ 50 ms).", "",
              "Earlier target: the extraction path runs at ≥ 0.5× the LogReader rate, i.e. the agent's own work "
              "costs at most as much as reading the file."]
    if prof is not None:
        shares, hottest, samples = prof
        lines += ["", f"**Profile** of one full `.blf` replay process (py-spy, {samples} samples at 250 Hz):", "",
                  "| where | share of the process's wall time |", "|---|---:|"]
        lines += [f"| {name} | {share:.0%} |" for name, share in shares]
        lines += ["", "Hottest functions by own time: " + "; ".join(f"{f} {share:.0%}" for f, share in hottest) + "."]
    lines += ["", PROFILE_NOTE, "", USER_RUN, "", CALIBRATION_GAP]
    write_report("\n".join(lines) + "\n", args.out)
    return 0


if __name__ == "__main__":
    sys.exit(main())
