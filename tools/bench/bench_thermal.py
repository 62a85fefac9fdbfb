"""Benchmark: what the lubricant thermal model adds to a KL cycle of a joint without motor temperature.

A learned :class:`~edge_monitor.features.kl_monitor.KLMonitor` with temperature compensation (the default friction
model, load compensation off) closes one cycle of n samples fed in 10 blocks, with a motor temperature (the
compensation smooths the friction reading) and without one (it follows the thermal model: the cycle's power
gathered from every block, a Kalman step at the cycle's end). The power is gathered on every joint (the
monitor cannot know before the cycle ends whether it carries a motor temperature), so both columns contain it;
its own time and the filter step's are timed alone too. Best of repeats, ratios in the same run.

    python tools/bench/bench_thermal.py
"""

from __future__ import annotations

import os
import platform
import sys

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import numpy as np  # noqa: E402
from benchmark_report import best_time  # noqa: E402

from edge_monitor.features.base import CycleInput  # noqa: E402
from edge_monitor.features.friction_extraction import FrictionCurve  # noqa: E402
from edge_monitor.features.kl_monitor import KLConfig, KLMonitor  # noqa: E402
from edge_monitor.features.lubricant_thermal_filter import CycleHeat, LubricantThermalFilter, ThermalObservation  # noqa: E402
from joint_model import FrictionParams  # noqa: E402

BLOCKS = 10


def kl_cycle_time(n: int, motor: float | None, rng: np.random.Generator) -> float:
    """Best time [s] of one KL cycle of ``n`` samples, with the given motor temperature (None: without)."""
    speed = np.tile(np.r_[np.full(50, 20.0), np.full(50, -20.0)], n // 100 + 1)[:n]
    torque = 0.05 * np.sign(speed) + 0.002 * rng.standard_normal(n)
    mon = KLMonitor(KLConfig(n_nominal_cycles=2, load_compensation="off"), FrictionParams())
    curve = FrictionCurve(speeds=[], torque=[], stderr=[])
    k = 0

    def one_cycle() -> object:
        nonlocal k
        for tau, v in zip(np.array_split(torque, BLOCKS), np.array_split(speed, BLOCKS)):
            mon.update_samples(tau, v)
        k += 1
        return mon.update(CycleInput(joint=0, cycle=k, t=110.0 * k, friction=curve, motor_temperature=motor),
                          {"temperature": 45.0 + 0.01 * k})

    for _ in range(3):                  # learn the nominal, start the filter
        one_cycle()
    return best_time(one_cycle, 30)


def main() -> int:
    rng = np.random.default_rng(0)
    f = LubricantThermalFilter()
    f.update(ThermalObservation(0.0, 7.5, 40.0))
    obs = ThermalObservation(110.0, 7.5, 41.0)
    step = best_time(lambda: [f.update(obs) for _ in range(1000)], 20) / 1000
    print(f"Python {platform.python_version()}, numpy {np.__version__}, {os.cpu_count()} cores (shared)\n")
    print(f"thermal filter step (predict + clipped correction): {1e6 * step:.1f} µs\n")
    print("| samples per cycle | with motor temperature [ms] | without (thermal model) [ms] | without / with "
          "| power gathering [ms] | its share of the cycle |")
    print("|---|---|---|---|---|---|")
    for n in (10_000, 100_000):
        with_t = kl_cycle_time(n, 50.0, rng)
        without = kl_cycle_time(n, None, rng)
        blocks = np.array_split(rng.standard_normal((2, n)), BLOCKS, axis=1)
        heat = CycleHeat()

        def gather_blocks(heat: CycleHeat = heat, blocks: list[np.ndarray] = blocks) -> None:
            for b in blocks:
                heat.add(b[0], b[1])

        gather = best_time(gather_blocks, 30)
        print(f"| {n:.0e} | {1e3 * with_t:.2f} | {1e3 * without:.2f} | {without / with_t:.2f} "
              f"| {1e3 * gather:.3f} | {gather / with_t:.1%} |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
