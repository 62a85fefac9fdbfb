"""Frames of simple synthetic test cycles built with the protocol encoders (no simulator).

Per cycle: back-and-forth plateaus at the given speed levels (friction from the §1 model at the
cycle's temperature, load and wear, plus inertia and gravity), a short production-like motion
(segment 200), status frames every 10 ticks. Used by agent tests that must not depend on the
simulator's physics.
"""

from __future__ import annotations

import numpy as np

from joint_model.friction import friction_magnitude
from protocol import frames as fr

RATE = 500.0


def cycle_profile(speeds, hold_s=1.2, ramp_s=0.1, pause_s=0.1, production=True):
    """Speed reference and segment codes of one cycle: per level ramp → +v hold → ramp → −v hold →
    ramp → pause, then (``production``) a sinusoidal production-like motion."""
    v_parts, seg_parts = [], []
    for k, v in enumerate(speeds):
        ramp = np.linspace(0, v, int(ramp_s * RATE), endpoint=False)
        hold = np.full(int(hold_s * RATE), v)
        part = np.concatenate([ramp, hold, ramp[::-1], -ramp, -hold, -ramp[::-1], np.zeros(int(pause_s * RATE))])
        v_parts.append(part)
        seg_parts.append(np.full(part.size, k + 1))
    if production:
        prod = 50.0 * np.sin(np.linspace(0, 4 * np.pi, int(1.0 * RATE)))
        v_parts.append(prod)
        seg_parts.append(np.full(prod.size, fr.SEGMENT_PRODUCTION))
    return np.concatenate(v_parts), np.concatenate(seg_parts)


def cycle_torque(speed, rng, load=0.5, temperature=40.0, wear=0.0, noise=2e-3, inertia=2e-4, gravity=None):
    """Motor torque along a speed profile: gravity + friction (§1 model) + inertia + white noise. The gravity
    torque is the load the gearbox carries, the |τl| of the friction model (as in the simulator), unless given."""
    acc = np.gradient(speed) * RATE
    gravity = load if gravity is None else gravity
    return (gravity + np.sign(speed) * friction_magnitude(speed, load, temperature, wear)
            + inertia * acc + rng.normal(0, noise, speed.size))


def make_frames(n_cycles, joints=(0,), speeds=(8.7, 41.7, 133.5), wear=lambda j, c: 0.0,
                temperature=lambda c: 40.0, load=0.5, load_std=0.1, noise=2e-3, seed=0,
                status=True, first_cycle=0, first_tick=0, start_tick=0, start_time=0.0,
                motor_temperature=lambda c: 45.0):
    """Return (ids, data[n,8], dlc, timestamps) of ``n_cycles`` cycles, in transmission order; the
    controller tick starts at ``start_tick`` (its 24-bit status field wraps) and timestamps at ``start_time`` s.
    ``first_cycle``/``first_tick``: where a stream made of several calls goes on (e.g. the ticks of
    ``first_cycle`` earlier cycles: ``first_cycle * cycle_profile(speeds)[0].size``), ticks and
    timestamps counted on from ``start_tick``/``start_time``. ``motor_temperature(cycle)``: what the
    joint status frames report [°C] (an operating condition only: the torque does not depend on it)."""
    rng = np.random.default_rng(seed)
    speed_ref, segment = cycle_profile(speeds)
    n_tick = speed_ref.size
    ids, rows, ts = [], [], []
    tick0 = start_tick + first_tick
    status_counter = first_tick // 10
    for c in range(n_cycles):
        cyc = first_cycle + c
        ticks = tick0 + np.arange(n_tick)
        per_joint = {}
        for j in joints:
            tau = cycle_torque(speed_ref, rng, load, temperature(cyc), wear(j, cyc), noise)
            per_joint[j] = fr.encode_motor_state_block(j, ticks % 256, tau, speed_ref, np.zeros(n_tick))
        load_est = load + rng.normal(0, load_std)
        for i in range(n_tick):
            t = start_time + (tick0 - start_tick + i) / RATE
            if status and i % 10 == 0:
                ids.append(fr.CONTROLLER_STATUS_ID)
                rows.append(fr.encode_controller_status(status_counter % 16, fr.Mode.TEST_CYCLE, cyc % 65536,
                                                        int(segment[i]), (tick0 + i) % (1 << 24)))
                ts.append(t)
                for j in joints:
                    ids.append(fr.JOINT_STATUS_BASE_ID + j)
                    rows.append(fr.encode_joint_status(j, status_counter % 16, load_est, load_std, motor_temperature(cyc)))
                    ts.append(t)
                status_counter += 1
            for j in joints:
                ids.append(fr.MOTOR_STATE_BASE_ID + j)
                rows.append(bytes(per_joint[j][i]))
                ts.append(t)
        tick0 += n_tick
    data = np.frombuffer(b"".join(rows), dtype=np.uint8).reshape(-1, 8).copy()
    return np.array(ids, dtype=np.int64), data, np.full(len(ids), 8), np.array(ts)
