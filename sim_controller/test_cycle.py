"""Speed-reference generator for one repetitive test cycle (docs/ALGORITHMS.md §2).

For each speed level k (segment k + 1): accelerate to +v, hold a plateau, reverse to −v, hold a
plateau of the same length, decelerate to 0 — the −v move passes back through the same angle
window, so the joint ends where it started — then a segment-0 pause. After the levels comes a
production-like point-to-point motion (segment 200) whose dwell between points (the
point-to-point delay) is drawn per cycle, then a final segment-0 pause.

The reference speed is piecewise linear in time (constant acceleration ramps); it is sampled at
the controller ticks and its integral (the reference angle) is computed exactly.
Units: speed rad/s (motor side), acceleration rad/s², angle rad, time s.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from protocol.frames import SEGMENT_NONE, SEGMENT_PRODUCTION

#: Displacements of the production moves as fractions of one production stroke (sum 0: returns).
PRODUCTION_MOVES: tuple[float, ...] = (1.0, -0.5, 0.75, -1.25, 0.4, -0.4)
#: Production stroke [rad, motor side].
PRODUCTION_STROKE = 80.0


@dataclass(frozen=True)
class CycleReference:
    """Reference of one cycle sampled at the ticks (arrays of length ``n``)."""

    speed: NDArray[np.float64]          # ω_ref [rad/s]
    acceleration: NDArray[np.float64]   # a_ref [rad/s²]
    angle: NDArray[np.float64]          # ∫ω_ref dt from the cycle start [rad]
    segment: NDArray[np.int64]          # 0, k + 1, or 200
    level: NDArray[np.int64]            # speed-level index k, −1 outside friction segments

    @property
    def n(self) -> int:
        return int(self.speed.size)


class _ProfileBuilder:
    """Collects (duration, end speed) pieces of a piecewise-linear speed profile with segment labels."""

    def __init__(self) -> None:
        self.times = [0.0]
        self.speeds = [0.0]
        self.seg_edges: list[tuple[float, int, int]] = []   # (start time, segment, level)

    @property
    def now(self) -> float:
        return self.times[-1]

    def mark(self, segment: int, level: int) -> None:
        self.seg_edges.append((self.now, segment, level))

    def to(self, speed: float, duration: float) -> None:
        if duration > 0:
            self.times.append(self.now + duration)
            self.speeds.append(speed)

    def ramp(self, speed: float, acceleration: float) -> None:
        self.to(speed, abs(speed - self.speeds[-1]) / acceleration)

    def hold(self, duration: float) -> None:
        self.to(self.speeds[-1], duration)

    def move(self, distance: float, max_speed: float, acceleration: float) -> None:
        """Point-to-point move from rest to rest (trapezoidal, triangular if short)."""
        sign = 1.0 if distance >= 0 else -1.0
        d = abs(distance)
        v = min(max_speed, np.sqrt(d * acceleration))
        t_ramp = v / acceleration
        t_hold = d / v - t_ramp
        self.to(sign * v, t_ramp)
        self.hold(t_hold)
        self.to(0.0, t_ramp)


def build_cycle(speeds: tuple[float, ...], rate: float, plateau_time: float, acceleration: float,
                pause_time: float, p2p_delay: float, production_speed: float) -> CycleReference:
    """Sample the reference of one cycle at ``rate`` Hz (tick i at time i / rate from the cycle start)."""
    b = _ProfileBuilder()
    for k, v in enumerate(speeds):
        b.mark(k + 1, k)
        b.ramp(v, acceleration)
        b.hold(plateau_time)
        b.ramp(-v, acceleration)
        b.hold(plateau_time)
        b.ramp(0.0, acceleration)
        b.mark(SEGMENT_NONE, -1)
        b.hold(pause_time)
    b.mark(SEGMENT_PRODUCTION, -1)
    for distance in PRODUCTION_MOVES:
        b.move(distance * PRODUCTION_STROKE, production_speed, acceleration)
        b.hold(p2p_delay)
    b.mark(SEGMENT_NONE, -1)
    b.hold(pause_time)
    return _sample(b, rate)


def _sample(b: _ProfileBuilder, rate: float) -> CycleReference:
    times = np.asarray(b.times)
    speeds = np.asarray(b.speeds)
    n = int(np.ceil(times[-1] * rate))
    t = np.arange(n) / rate
    idx = np.clip(np.searchsorted(times, t, side="right") - 1, 0, times.size - 2)
    dt_piece = np.diff(times)
    slope = np.diff(speeds) / dt_piece
    # exact integral of the piecewise-linear speed at the breakpoints
    angle_at_break = np.concatenate([[0.0], np.cumsum(0.5 * (speeds[:-1] + speeds[1:]) * dt_piece)])
    tau = t - times[idx]
    speed = speeds[idx] + slope[idx] * tau
    angle = angle_at_break[idx] + speeds[idx] * tau + 0.5 * slope[idx] * tau**2
    edge_t = np.asarray([e[0] for e in b.seg_edges])
    edge_i = np.clip(np.searchsorted(edge_t, t, side="right") - 1, 0, edge_t.size - 1)
    segment = np.asarray([e[1] for e in b.seg_edges], dtype=np.int64)[edge_i]
    level = np.asarray([e[2] for e in b.seg_edges], dtype=np.int64)[edge_i]
    return CycleReference(speed=speed, acceleration=slope[idx], angle=angle, segment=segment, level=level)


def cycle_duration(speeds: tuple[float, ...], plateau_time: float, acceleration: float, pause_time: float,
                   p2p_delay: float, production_speed: float) -> float:
    """Length of one cycle [s] (for planning; 1 kHz sampling is enough for the estimate)."""
    ref = build_cycle(speeds, 1000.0, plateau_time, acceleration, pause_time, p2p_delay, production_speed)
    return ref.n / 1000.0
