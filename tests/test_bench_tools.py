"""Correctness of the benchmark tools' own logic (no speed assertions): the River tuning bisection
of tools/bench/bench_detection.py, and how every tool writes its report."""

from __future__ import annotations

import math
import sys
from pathlib import Path

import numpy as np
import pytest

TOOLS = Path(__file__).resolve().parents[1] / "tools"
sys.path[:0] = [str(TOOLS / "bench"), str(TOOLS / "studies"), str(TOOLS / "soak")]

import bench_detection as bd  # noqa: E402


def test_bisection_finds_the_target_of_a_monotone_function() -> None:
    # ARL0 = 1/p (a larger p alarms more): p = 1/250 gives 250
    p, a = bd.bisect_param(lambda p: 1.0 / p, 250.0, 1e-9, 1.0, larger_is_stricter=False, steps=40)
    assert a == pytest.approx(250.0, rel=1e-6) and p == pytest.approx(1 / 250, rel=1e-6)
    p, a = bd.bisect_param(lambda p: 3.0 * p, 90.0, 1e-3, 1e4, larger_is_stricter=True, steps=40)
    assert a == pytest.approx(90.0, rel=1e-6)


def test_bisection_without_alarm_target_takes_the_most_lenient_alarm_free_setting() -> None:
    # no alarm (inf) for p ≥ 5, alarms below: the answer converges to 5 from above
    p, a = bd.bisect_param(lambda p: math.inf if p >= 5 else 10.0, math.inf, 1e-3, 1e3, larger_is_stricter=True,
                           steps=40)
    assert math.isinf(a) and p == pytest.approx(5.0, rel=1e-6)


def test_river_page_hinkley_tuned_to_a_measured_arl0_on_synthetic_sequences() -> None:
    pytest.importorskip("river")
    rng = np.random.default_rng(3)
    streams = [(rng.normal(size=400).tolist(), list(range(400))) for _ in range(15)]
    spec = next(s for s in bd.river_specs() if s.name.startswith("PageHinkley (up, δ=0.75"))
    target = 150.0
    p, a = bd.bisect_param(lambda p: bd.river_arl0(spec, p, streams), target, spec.low, spec.high,
                           spec.larger_is_stricter, steps=16)
    assert a == pytest.approx(target, rel=0.25)
    assert bd.river_arl0(spec, p, streams) == a             # deterministic


def test_river_run_restarts_after_a_false_alarm_and_reports_the_first_alarm_after_the_start() -> None:
    pytest.importorskip("river")
    spec = next(s for s in bd.river_specs() if s.name.startswith("PageHinkley (up, δ=0.75"))
    xs = [0.0] * 100 + [50.0] + [0.0] * 99 + [5.0] * 100      # a spike at 100, a sustained step at 200
    n, false_alarms, hits = bd.river_run(spec, 5.0, xs, list(range(300)), start=150)
    assert n == 300 and false_alarms == 1 and hits and 200 <= hits[0] < 210


# -- tools/bench/bench_live.py (latency): link times, received symptoms, percentiles ----------------------------

import bench_live  # noqa: E402


class _T:
    def __init__(self, index: int, key: tuple[int, int], pred: tuple[int, int] | None) -> None:
        self.index, self.key, self.pred = index, key, pred


def test_cycle_end_is_the_time_of_the_frame_before_the_next_cycles_first_status() -> None:
    # chunks: frames [0, 100) at t=1.0, [100, 250) at t=2.0, [250, 400) at t=3.0
    chunks = [(100, 1.0), (250, 2.0), (400, 3.0)]
    assert bench_live.chunk_time(chunks, 0) == 1.0
    assert bench_live.chunk_time(chunks, 99) == 1.0
    assert bench_live.chunk_time(chunks, 100) == 2.0
    assert bench_live.chunk_time(chunks, 399) == 3.0
    assert bench_live.chunk_time(chunks, 400) is None
    transitions = [_T(0, (0, 0), None), _T(100, (0, 1), (0, 0)), _T(250, (0, 2), (0, 1)),
                   _T(300, (0, 5), (0, 2))]       # a jump: cycle 2 did not end with cycle 3 → no end time
    ends = bench_live.cycle_end_times(transitions, chunks, {0: 10})
    assert ends == {10: 1.0, 11: 2.0}


def test_received_symptoms_first_complete_arrival_and_latencies(tmp_path: Path) -> None:
    path = tmp_path / "got.jsonl"
    lines = [
        {"robot": "r", "joint": 0, "cycle": 10, "partial": False, "t": 1, "recv": 1.05},
        {"robot": "r", "joint": 1, "cycle": 10, "partial": False, "t": 1, "recv": 1.08},
        {"robot": "r", "joint": 0, "cycle": 10, "partial": False, "t": 1, "recv": 1.5},   # duplicate: first counts
        {"robot": "r", "joint": 0, "cycle": 11, "partial": True, "t": 2, "recv": 2.01},   # partial: left out
        {"robot": "r", "joint": 1, "cycle": 12, "partial": False, "t": 3, "recv": 3.2},   # no end time
        {"misses": 0},
    ]
    path.write_text("\n".join(__import__("json").dumps(x) for x in lines) + "\nnot json\n")
    received = bench_live.read_received(path)
    assert received == {(0, 10): 1.05, (1, 10): 1.08, (1, 12): 3.2}
    every, last = bench_live.latencies({10: 1.0, 11: 2.0}, received)
    assert sorted(every) == pytest.approx([0.05, 0.08]) and last == pytest.approx([0.08])


def test_percentile_is_nearest_rank() -> None:
    values = [float(v) for v in range(1, 101)]
    assert bench_live.percentile(values, 50) == 50.0
    assert bench_live.percentile(values, 99) == 99.0
    assert bench_live.percentile([3.0], 99) == 3.0
    assert math.isnan(bench_live.percentile([], 50))


def test_a_benchmark_report_goes_to_stdout_its_doc_file_and_optionally_json(tmp_path: Path, capsys) -> None:
    from benchmark_report import write_report

    out = tmp_path / "docs" / "bench.md"
    write_report("| a | b |\n", out)
    assert out.read_text() == "| a | b |\n" and "| a | b |" in capsys.readouterr().out
    write_report("x", out, tmp_path / "raw.json", {"v": np.float64(1.5)}, default=float)
    assert '"v": 1.5' in (tmp_path / "raw.json").read_text()
    write_report("x", out, tmp_path / "raw.json", {"p": tmp_path / "w"})      # default str: paths readable
    assert str(tmp_path / "w") in (tmp_path / "raw.json").read_text()


def test_kl_study_tools_run_on_the_agents_kl_monitor() -> None:
    """eval_kl_weights and bench_kde drive the agent's KLMonitor (they broke silently once when its
    constructor changed): wear 35 at a constant temperature is found in every cycle (Pd at 1 % false
    alarms = 1), and the per-cycle cost table has its two rows."""
    import bench_kde
    import eval_kl_weights as ekw

    rng = np.random.default_rng(2)
    pd = ekw.study(ekw.model_cycles, [0.0], n_cycles=12, replicates=1, k=3, wear=35.0,
                   weights={"published": ekw.PUBLISHED}, rng=rng)
    assert pd == {"raw": {0.0: [1.0]}, "published": {0.0: [1.0]}}
    rows = [line for line in bench_kde.monitor_rows(rng) if line.startswith("| 1e")]
    assert len(rows) == 2 and all(float(cell) > 0 for row in rows for cell in row.strip("|").split("|")[1:3])


def test_the_sequential_study_traces_the_agents_detector() -> None:
    """arl_study's sequential part: one statistic per monitored cycle, never negative."""
    import arl_study

    trace = arl_study.h0_trace("gaussian", 40, np.random.default_rng(1), density="gauss", n_nominal=20)
    assert trace.shape == (40,) and (trace >= 0).all()
