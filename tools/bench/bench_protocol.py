#!/usr/bin/env python3
"""Benchmark: protocol decode + E2E check cost relative to iterating python-can's LogReader.

Records a realistic .blf (6 joints x MotorState at 500 Hz + ControllerStatus/JointStatus every
10th tick) with the protocol encoders into a temporary directory, then times, in this process:

  baseline   iterate ``can.LogReader`` over the file (nothing else)
  block      messages_to_arrays + decode_block + E2EReceiver.check_block in blocks of 4096
             (timed on the already-read messages, i.e. the protocol layer alone)
  pipeline   LogReader iteration + the block path, end to end
  message    decode_message + E2EReceiver.check per message (the live-loop path)

Times are CPU seconds of this process (time.process_time), minimum over repetitions.

Reports ratios to the baseline (target: block / baseline <= 1/3) and writes
docs/benchmarks/protocol.md.  Usage: ``python tools/bench/bench_protocol.py [--frames N] [--repeat R]``.
"""

from __future__ import annotations

import argparse
import platform
import tempfile
import time
from pathlib import Path

import can
import numpy as np
from benchmark_report import write_report

from protocol import frames as F
from protocol.e2e import E2EReceiver

JOINTS = 6
RATE_HZ = 500.0
STATUS_EVERY = 10
BLOCK = 4096
REPO = Path(__file__).resolve().parents[2]
_clock = time.process_time  # CPU time of this process: robust on a machine shared with other jobs


def record_blf(path: Path, n_frames: int) -> int:
    """Write about n_frames realistic protected frames to ``path``; returns the exact count."""
    frames_per_tick = JOINTS + (1 + JOINTS) / STATUS_EVERY
    n_ticks = int(n_frames / frames_per_tick)
    ticks = np.arange(n_ticks)
    t = ticks / RATE_HZ
    rows = [
        F.encode_motor_state_block(j, ticks, 0.3 * np.sin(2 * np.pi * 0.2 * t + j), 50 * np.sin(2 * np.pi * 0.1 * t),
                                   np.cumsum(np.full(n_ticks, 0.01)))
        for j in range(JOINTS)
    ]
    writer = can.Logger(path)
    count = 0
    for tick in range(n_ticks):
        stamp = 1_700_000_000.0 + tick / RATE_HZ
        for j in range(JOINTS):
            writer.on_message_received(F.to_message(F.MOTOR_STATE_BASE_ID + j, rows[j][tick].tobytes(), stamp))
        count += JOINTS
        if tick % STATUS_EVERY == 0:
            status_counter = tick // STATUS_EVERY
            writer.on_message_received(F.to_message(
                F.CONTROLLER_STATUS_ID,
                F.encode_controller_status(status_counter, F.Mode.TEST_CYCLE, tick // 10_000, 3, tick), stamp))
            for j in range(JOINTS):
                writer.on_message_received(F.to_message(
                    F.JOINT_STATUS_BASE_ID + j, F.encode_joint_status(j, status_counter, 0.1, 0.01, 40.0), stamp))
            count += 1 + JOINTS
    writer.stop()
    return count


def time_baseline(path: Path) -> float:
    start = _clock()
    for _ in can.LogReader(path):
        pass
    return _clock() - start


def _process_blocks(messages: list[can.Message], receiver: E2EReceiver) -> int:
    usable = 0
    for begin in range(0, len(messages), BLOCK):
        ids, data, dlc, timestamps = F.messages_to_arrays(messages[begin:begin + BLOCK])
        block = F.decode_block(ids, data, dlc)
        statuses, _ = receiver.check_block(ids, block.counter, block.crc_ok, timestamps)
        usable += int(np.count_nonzero(statuses <= 1))
    return usable


def time_block(messages: list[can.Message]) -> tuple[float, int]:
    receiver = E2EReceiver()
    start = _clock()
    usable = _process_blocks(messages, receiver)
    return _clock() - start, usable


def time_pipeline(path: Path) -> float:
    receiver = E2EReceiver()
    start = _clock()
    pending: list[can.Message] = []
    for msg in can.LogReader(path):
        pending.append(msg)
        if len(pending) == BLOCK:
            _process_blocks(pending, receiver)
            pending = []
    _process_blocks(pending, receiver)
    return _clock() - start


def time_per_message(messages: list[can.Message]) -> tuple[float, int]:
    receiver = E2EReceiver()
    usable = 0
    start = _clock()
    for msg in messages:
        frame = F.decode_message(msg)
        if isinstance(frame, F.DecodeError):
            receiver.check(msg.arbitration_id, -1, False, msg.timestamp)
            continue
        counter = frame.tick if isinstance(frame, F.MotorState) else frame.counter
        status, _ = receiver.check(msg.arbitration_id, counter, True, msg.timestamp)
        usable += status <= 1
    return _clock() - start, usable


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--frames", type=int, default=200_000, help="frames in the recording")
    parser.add_argument("--repeat", type=int, default=5, help="repetitions; the minimum time is reported")
    parser.add_argument("--out", type=Path, default=REPO / "docs" / "benchmarks" / "protocol.md")
    args = parser.parse_args()

    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "bench.blf"
        n = record_blf(path, args.frames)
        messages = list(can.LogReader(path))
        assert len(messages) == n
        baseline = min(time_baseline(path) for _ in range(args.repeat))
        block_runs = [time_block(messages) for _ in range(args.repeat)]
        block = min(t for t, _ in block_runs)
        pipeline = min(time_pipeline(path) for _ in range(args.repeat))
        message_runs = [time_per_message(messages) for _ in range(max(1, args.repeat // 2))]
        per_message = min(t for t, _ in message_runs)
        assert block_runs[0][1] == message_runs[0][1] == n, "every frame of the clean recording must be usable"

    rows = [
        ("LogReader iteration (baseline)", baseline),
        ("protocol, block path (arrays + decode_block + check_block)", block),
        ("LogReader + block path, end to end", pipeline),
        ("protocol, per-message path (decode_message + check)", per_message),
    ]
    lines = [
        "## Protocol decode + E2E check (`tools/bench/bench_protocol.py`)",
        "",
        f"{n} frames in a .blf ({JOINTS} joints x MotorState at {RATE_HZ:.0f} Hz + status every "
        f"{STATUS_EVERY}th tick), blocks of {BLOCK}; minimum of {args.repeat} runs; "
        f"Python {platform.python_version()}, numpy {np.__version__}, python-can {can.__version__}, "
        f"{platform.machine()}. Times are CPU seconds of the benchmark process (`time.process_time`), "
        "because the machine is shared with other jobs and wall time is dominated by them; all "
        "paths run back to back in one process.",
        "",
        "| path | time (s) | frames/s | ratio to LogReader |",
        "|---|---|---|---|",
    ]
    for name, seconds in rows:
        lines.append(f"| {name} | {seconds:.3f} | {n / seconds:,.0f} | {seconds / baseline:.3f} |")
    verdict = "meets" if block / baseline <= 1 / 3 else "MISSES"
    lines += [
        "",
        f"Protocol layer (block path) costs **{block / baseline:.2f}x** the LogReader iteration time "
        f"(target <= 0.33: {verdict}); the per-message path costs {per_message / baseline:.2f}x.",
        "",
    ]
    write_report("\n".join(lines), args.out)


if __name__ == "__main__":
    main()
