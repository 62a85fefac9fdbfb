"""The simulated robot controller: joints, test cycles, frames, ground truth.

``Controller(config).frames()`` yields :class:`~sim_controller.faults.FrameBlock` s (ids, data
[n, 8], timestamps in controller time) in send order, already through the fault injector; ground
truth accumulates per joint and cycle (``truth_records()`` / ``drain_truth()``) and
``summary()`` gives the fault counters and the number of frames emitted.

Per controller tick: one MotorState frame per joint (alive counter = tick mod 256); every 10th
tick a ControllerStatus (counter mod 16, mode, cycle, segment, 24-bit tick) followed by one
JointStatus per joint (load estimate, its σl, motor temperature). Frames of one tick are spaced
by the time one 8-byte frame takes on a 1 Mbit/s bus, so timestamps strictly increase.

Per cycle and joint (constant within the cycle): manipulation load |τl| ~ U(load_range) with the
joint's gravity sign, the controller's estimate μl = (1 + payload_error)·τl + N(0, σl²), the lubricant temperature
(thermal model or uniform draw), the wear level of the joint's scenario, and a friction model
error δk ~ N(0, σm²) per speed level k, added to the friction magnitude in both directions.
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass, replace
from typing import Any, Iterator

import numpy as np
from numpy.typing import NDArray

from joint_model.friction import FrictionParams, friction_magnitude, nominal_friction, wear_friction
from protocol import frames as pf
from sim_controller.config import SimConfig
from sim_controller.faults import FaultInjector, FrameBlock
from sim_controller.joint_dynamics import SpeedLoop, SpeedLoopParams, simulate_block
from sim_controller.test_cycle import CycleReference, build_cycle
from sim_controller.thermal import ThermalModel
from sim_controller.timeline import PlantConditions

log = logging.getLogger(__name__)

#: Status frames are sent every this many controller ticks.
STATUS_EVERY = 10
#: Bus time of one 8-byte classical CAN frame at 1 Mbit/s (no stuffing) [s].
FRAME_TIME_S = 111e-6
#: Gear ratio motor : joint of every simulated joint.
GEAR_RATIO = 120.0
#: Friction parameters that get individual variation (the signs and Stribeck speeds of the
#: temperature term are kept: their ratio decides where the model is valid).
VARIED_PARAMS = ("fc0", "fcl", "fsl", "fsxi", "fv0", "fvxi", "vsl", "fsw", "fvw")
#: Length of the STOPPED period before the first cycle after a gearbox replacement [s].
MAINTENANCE_STOP_S = 1.0
#: Motor winding temperature = lubricant + this offset + a per-cycle N(0, 3²) deviation [°C].
MOTOR_TEMPERATURE_OFFSET = 5.0
MOTOR_TEMPERATURE_CYCLE_STD = 3.0
MOTOR_TEMPERATURE_FRAME_STD = 0.05


@dataclass(frozen=True)
class JointSetup:
    """Fixed properties of one simulated joint (recorded in the truth sidecar)."""

    joint: int
    friction: FrictionParams
    loop: SpeedLoopParams
    gear_ratio: float
    test_angle: float        # joint angle of the friction test [rad]
    load_sign: float         # sign of the gravity torque at the test angle

    def to_dict(self) -> dict[str, Any]:
        return {"joint": self.joint, "friction": self.friction.to_dict(),
                "inertia": self.loop.inertia, "kp": self.loop.kp, "ki": self.loop.ki,
                "gear_ratio": self.gear_ratio, "test_angle": self.test_angle, "load_sign": self.load_sign}


@dataclass(frozen=True)
class CycleConditions:
    """Per-joint conditions of one cycle (arrays of length ``joints``; model_error joints × levels), the
    plant conditions in effect (timeline) and the hours the robot stood still before the cycle."""

    plant: PlantConditions
    stop_hours: float
    load: NDArray[np.float64]
    load_estimate: NDArray[np.float64]
    temperature: NDArray[np.float64]
    wear: NDArray[np.float64]
    model_error: NDArray[np.float64]
    motor_temperature: NDArray[np.float64]
    maintenance: NDArray[np.bool_]
    p2p_delay: float


@dataclass(frozen=True)
class SimulatedCycle:
    """One simulated cycle before encoding: conditions, reference, the joints' signals (``sim``:
    torque, speed, position, load estimate; joints × samples), controller ticks, and the per-frame
    noise of the motor temperatures the status frames will carry (joints × status frames)."""

    cycle: int
    cond: CycleConditions
    ref: CycleReference
    mode: NDArray[np.int64]
    sim: dict[str, NDArray[np.float64]]
    ticks: NDArray[np.int64]
    abs_tick: int
    status_count: int
    status_noise: NDArray[np.float64]


def make_joint_setups(config: SimConfig, rng: np.random.Generator) -> list[JointSetup]:
    """Joint 0 … n−1 with seeded individual variation of the friction parameters."""
    spread = config.effective_variation()
    setups = []
    for j in range(config.joints):
        factors = rng.uniform(1.0 - spread, 1.0 + spread, size=len(VARIED_PARAMS))
        params = config.friction
        if spread > 0:
            params = replace(params, **{n: getattr(params, n) * float(f) for n, f in zip(VARIED_PARAMS, factors)})
        load_sign = 1.0
        override = config.joint_overrides[j] if j < len(config.joint_overrides) else None
        if override is not None:
            params = override.friction or params
            load_sign = override.load_sign if override.load_sign is not None else load_sign
        setups.append(JointSetup(joint=j, friction=params, loop=SpeedLoopParams(), gear_ratio=GEAR_RATIO,
                                 test_angle=0.3 + 0.25 * j, load_sign=load_sign))
    return setups


def stop_ticks(hours: float, rate: float) -> int:
    """Controller ticks of a plant stop of ``hours`` (rounded to a tick)."""
    return int(round(hours * 3600.0 * rate))


def statuses_between(tick: int, gap: int) -> int:
    """Status frames a running controller sends in the ticks ``tick`` … ``tick + gap − 1`` (every
    ``STATUS_EVERY``-th tick): the status counter moves on by this during a stop."""
    return -(-(tick + gap) // STATUS_EVERY) - -(-tick // STATUS_EVERY)


class Controller:
    """Simulated controller of one robot (see module docstring). Deterministic given ``config.seed``."""

    def __init__(self, config: SimConfig, encoder: Any = None) -> None:
        self.config = config
        self.encoder = encoder       # another controller's frames (sim_controller.profiles); None: ours
        seeds = np.random.SeedSequence(config.seed).spawn(6)
        setup_rng, self._cycle_rng, self._noise_rng, fault_rng, self._restart_rng, _ = (
            np.random.default_rng(s) for s in seeds)
        self.joints = make_joint_setups(config, setup_rng)
        self._loop = SpeedLoop(SpeedLoopParams(), config.rate, config.joints)
        self._thermal = [ThermalModel(temperature=config.start_temperature, ambient=config.ambient,
                                      time_constant=config.thermal_time_constant, heating=config.heating,
                                      time_acceleration=config.time_acceleration) for _ in range(config.joints)]
        self.injector = FaultInjector(config.faults, fault_rng, pf.frame_crc_block)
        self._truth: list[dict[str, Any]] = []
        self._drained = 0
        self.frames_emitted = 0
        self.ticks_done = 0
        self.cycles_done = 0
        n_per_tick = config.joints * 2 + 1
        self._frame_spacing = min(FRAME_TIME_S, 0.9 / (config.rate * n_per_tick))

    # -- public API -----------------------------------------------------------------------------

    @property
    def simulated_seconds(self) -> float:
        return self.ticks_done / self.config.rate

    def simulated_cycles(self) -> Iterator["SimulatedCycle"]:
        """The physics of every cycle of the run, in order, without frames (the cycle-level mode of
        :mod:`sim_controller.cycle_mode` and the frame encoder share it). Ground truth is recorded and
        the thermal state advanced before each cycle is yielded."""
        c = self.config
        abs_tick = 0          # ticks since the start (timestamps)
        tick_base = 0         # abs tick of the last (re)start: controller tick = abs_tick − tick_base
        status_count = 0
        for cycle in range(c.cycles):
            plant, stop_hours = c.conditions(cycle), c.stop_hours(cycle)
            for model in self._thermal:
                model.ambient = plant.ambient
            if stop_hours > 0:
                gap = stop_ticks(stop_hours, c.rate)
                self._advance_thermal(gap / c.rate, np.zeros(c.joints))
                status_count += statuses_between(abs_tick - tick_base, gap)
                abs_tick += gap
            restarted = c.faults.restart > 0 and self._restart_rng.random() < c.faults.restart
            if restarted:
                abs_tick += int(round(c.faults.restart_gap * c.rate))
                tick_base = abs_tick
                status_count = 0
                self.injector.counts["restarts"] += 1
            cond = self._draw_conditions(cycle, plant, stop_hours)
            ref, mode = self._reference(cond)
            sim = self._simulate(ref, cond)
            ticks = np.arange(abs_tick, abs_tick + ref.n) - tick_base
            n_status = int(np.count_nonzero(ticks % STATUS_EVERY == 0))
            status_noise = self._noise_rng.normal(0.0, MOTOR_TEMPERATURE_FRAME_STD, size=(c.joints, n_status))
            self._record_truth(cycle, cond, abs_tick, ref.n, restarted)
            self._advance_thermal(ref.n / c.rate, sim["power"])
            yield SimulatedCycle(cycle, cond, ref, mode, sim, ticks, abs_tick, status_count, status_noise)
            status_count += n_status
            abs_tick += ref.n

    def frames(self) -> Iterator[FrameBlock]:
        """All frames of the run, in blocks of about ``config.block_time`` seconds."""
        for sc in self.simulated_cycles():
            if self.encoder is None:
                yield from self._emit(self._encode(sc), sc.ticks)
            else:
                block, per_tick = self.encoder.encode(sc, self._frame_spacing)
                yield from self._emit(block, sc.ticks, per_tick)
            self.cycles_done += 1
        tail = self.flush_link()
        if len(tail):
            yield tail

    def flush_link(self) -> FrameBlock:
        """Frames the fault injector still holds back (delayed ones), for the end of a run or a stop."""
        tail = self.injector.flush()
        self.frames_emitted += len(tail)
        return tail

    def truth_records(self) -> list[dict[str, Any]]:
        """Ground truth so far: one record per joint per completed cycle."""
        return list(self._truth)

    def drain_truth(self) -> list[dict[str, Any]]:
        """Truth records not returned by a previous ``drain_truth`` call."""
        new = self._truth[self._drained:]
        self._drained = len(self._truth)
        return new

    def summary(self) -> dict[str, Any]:
        """Last truth line: fault counters and frames emitted (after faults)."""
        return {"faults": dict(self.injector.counts), "frames_sent": self.frames_emitted}

    def parameters(self) -> dict[str, Any]:
        """Per-joint parameters actually used (truth sidecar: lets commissioning be checked)."""
        c = self.config
        return {"joints": [s.to_dict() for s in self.joints], "rate": c.rate, "seed": c.seed,
                "speeds": list(c.speeds), "variation": c.effective_variation(),
                "friction_model_error": c.friction_model_error, "torque_noise": c.torque_noise,
                "speed_noise": c.speed_noise, "load_range": list(c.load_range), "load_std": c.load_std,
                "payload_error": c.payload_error,
                "temperature_range": None if c.temperature_range is None else list(c.temperature_range),
                "thermal_time_constant": c.thermal_time_constant, "time_acceleration": c.time_acceleration,
                "wear": [c.wear_profile(j).to_dict() for j in range(c.joints)], "faults": c.faults.to_dict(),
                "timeline": [event.to_dict() for event in c.timeline]}

    # -- one cycle ------------------------------------------------------------------------------

    def _draw_conditions(self, cycle: int, plant: PlantConditions, stop_hours: float) -> CycleConditions:
        c, rng, n = self.config, self._cycle_rng, self.config.joints
        magnitude = rng.uniform(plant.load_range[0], plant.load_range[1], size=n)
        load = magnitude * np.array([s.load_sign for s in self.joints])
        estimate = load * (1.0 + plant.payload_error) + rng.normal(0.0, plant.load_std, size=n)
        if c.temperature_range is not None:
            temperature = rng.uniform(c.temperature_range[0], c.temperature_range[1], size=n)
        else:
            temperature = np.maximum([m.temperature for m in self._thermal], c.min_temperature)
        model_error = rng.normal(0.0, c.friction_model_error, size=(n, len(c.speeds)))
        motor_temperature = temperature + MOTOR_TEMPERATURE_OFFSET + rng.normal(0.0, MOTOR_TEMPERATURE_CYCLE_STD, n)
        p2p_delay = float(rng.uniform(*c.p2p_delay))
        wear = np.array([c.wear_profile(j).wear(cycle) for j in range(n)])
        maintenance = np.array([c.wear_profile(j).maintenance(cycle) for j in range(n)])
        return CycleConditions(plant, stop_hours, load, estimate, np.asarray(temperature, dtype=float), wear,
                               model_error, motor_temperature, maintenance, p2p_delay)

    def _reference(self, cond: CycleConditions) -> tuple[CycleReference, NDArray[np.int64]]:
        c = self.config
        ref = build_cycle(c.speeds, c.rate, c.plateau_time, c.acceleration, c.pause_time, cond.p2p_delay,
                          c.production_speed)
        mode = np.where(ref.segment == pf.SEGMENT_PRODUCTION, int(pf.Mode.PRODUCTION), int(pf.Mode.TEST_CYCLE))
        if cond.maintenance.any():   # the robot stood still (STOPPED) while the gearbox was replaced
            stop = int(round(MAINTENANCE_STOP_S * c.rate))
            zeros = np.zeros(stop)
            ref = CycleReference(np.concatenate([zeros, ref.speed]), np.concatenate([zeros, ref.acceleration]),
                                 np.concatenate([zeros, ref.angle]),
                                 np.concatenate([np.zeros(stop, np.int64), ref.segment]),
                                 np.concatenate([np.full(stop, -1, np.int64), ref.level]))
            mode = np.concatenate([np.full(stop, int(pf.Mode.STOPPED)), mode])
        return ref, mode

    def _simulate(self, ref: CycleReference, cond: CycleConditions) -> dict[str, NDArray[np.float64]]:
        c, n_j = self.config, self.config.joints
        production = ref.segment == pf.SEGMENT_PRODUCTION
        joint_angle = (ref.angle / GEAR_RATIO)[None, :]
        # gravity: constant τl over the friction segments, τl·cos(Δq) on the production path
        shape = np.where(production[None, :], np.cos(joint_angle), 1.0)
        gravity = cond.load[:, None] * shape
        gravity_ff = cond.load_estimate[:, None] * shape
        offsets = np.where(ref.level[None, :] >= 0, cond.model_error[:, np.maximum(ref.level, 0)], 0.0)
        setups = self.joints

        def friction_fn(speed: NDArray[np.float64], mask: NDArray[np.bool_] | None,
                        previous: NDArray[np.float64] | None) -> NDArray[np.float64]:
            out = np.empty_like(speed) if previous is None else previous.copy()
            for j in range(n_j):
                cols = slice(None) if mask is None else mask[j]
                v = speed[j, cols]
                magnitude = nominal_friction(v, cond.load[j], cond.temperature[j], setups[j].friction)
                if cond.wear[j] > 0:
                    magnitude = magnitude + wear_friction(v, cond.wear[j], setups[j].friction)
                out[j, cols] = np.sign(v) * (magnitude + offsets[j, cols])
            return out

        resp = simulate_block(self._loop, ref.speed, ref.acceleration, gravity, gravity_ff, friction_fn)
        noise = self._noise_rng
        torque = resp.torque + noise.normal(0.0, c.torque_noise, size=resp.torque.shape)
        speed = resp.speed + noise.normal(0.0, c.speed_noise, size=resp.speed.shape)
        motor_angle = np.array([s.test_angle * s.gear_ratio for s in setups])[:, None] + ref.angle - resp.angle_error
        # JointStatus carries the controller's estimate μl of the load torque at the test angle, constant
        # over the cycle (the production path's cos(Δq) gravity model stays inside the controller)
        load_estimate = np.broadcast_to(cond.load_estimate[:, None], gravity_ff.shape)
        power = np.mean(np.abs(resp.friction * resp.speed), axis=1)
        return {"torque": torque, "speed": speed, "position": np.mod(motor_angle, 2.0 * math.pi),
                "load_estimate": load_estimate, "power": power}

    def _encode(self, sc: "SimulatedCycle") -> FrameBlock:
        ref, mode, cond, sim, ticks, cycle = sc.ref, sc.mode, sc.cond, sc.sim, sc.ticks, sc.cycle
        c, n_j, n = self.config, self.config.joints, ref.n
        status = ticks % STATUS_EVERY == 0
        n_status = int(status.sum())
        before = np.arange(n) * n_j + (np.cumsum(status) - status) * (n_j + 1)
        total = n * n_j + n_status * (n_j + 1)
        ids = np.empty(total, dtype=np.int64)
        data = np.empty((total, 8), dtype=np.uint8)
        ts = np.empty(total)
        t_tick = c.start_time + (sc.abs_tick + np.arange(n)) / c.rate
        for j in range(n_j):
            pos = before + j
            ids[pos] = pf.MOTOR_STATE_BASE_ID + j
            data[pos] = pf.encode_motor_state_block(j, ticks, sim["torque"][j], sim["speed"][j], sim["position"][j])
            ts[pos] = t_tick + j * self._frame_spacing
        st = np.flatnonzero(status)
        base = before[st] + n_j
        ids[base] = pf.CONTROLLER_STATUS_ID
        ts[base] = t_tick[st] + n_j * self._frame_spacing
        counters = sc.status_count + np.arange(st.size)
        data[base] = pf.encode_controller_status_block(counters, mode[st], cycle, ref.segment[st], ticks[st])
        for j in range(n_j):
            pos = base + 1 + j
            ids[pos] = pf.JOINT_STATUS_BASE_ID + j
            ts[pos] = t_tick[st] + (n_j + 1 + j) * self._frame_spacing
            data[pos] = pf.encode_joint_status_block(j, counters, sim["load_estimate"][j, st], cond.plant.load_std,
                                                  cond.motor_temperature[j] + sc.status_noise[j])
        return FrameBlock(ids, data, ts)

    def _emit(self, block: FrameBlock, ticks: NDArray[np.int64],
              frames_per_tick: NDArray[np.int64] | None = None) -> Iterator[FrameBlock]:
        c = self.config
        n_j = c.joints
        if frames_per_tick is None:
            status = ticks % STATUS_EVERY == 0
            frames_per_tick = n_j + status * (n_j + 1)
        starts = np.concatenate([[0], np.cumsum(frames_per_tick)])
        step = max(1, int(round(c.block_time * c.rate)))
        for i0 in range(0, ticks.size, step):
            i1 = min(ticks.size, i0 + step)
            part = block.take(np.arange(starts[i0], starts[i1]))
            out = self.injector.apply(part) if (c.faults.any_link_fault or self.injector.holding) else part
            self.frames_emitted += len(out)
            self.ticks_done += i1 - i0
            if len(out):
                yield out

    def _record_truth(self, cycle: int, cond: CycleConditions, abs_tick: int, n: int, restarted: bool) -> None:
        c = self.config
        speeds = np.asarray(c.speeds)
        for j, setup in enumerate(self.joints):
            model = friction_magnitude(speeds, cond.load[j], cond.temperature[j], cond.wear[j], setup.friction)
            self._truth.append({
                "joint": j, "cycle": cycle,
                "temperature": float(cond.temperature[j]), "load": float(cond.load[j]),
                "load_estimate": float(cond.load_estimate[j]), "load_std": cond.plant.load_std,
                "load_range": list(cond.plant.load_range), "ambient": cond.plant.ambient,
                "payload_error": cond.plant.payload_error, "stop_hours": cond.stop_hours,
                "wear": float(cond.wear[j]), "maintenance": bool(cond.maintenance[j]), "restart": restarted,
                "motor_temperature": float(cond.motor_temperature[j]), "p2p_delay": cond.p2p_delay,
                "t_start": c.start_time + abs_tick / c.rate, "t_end": c.start_time + (abs_tick + n) / c.rate,
                "speeds": [float(v) for v in speeds], "friction": [float(v) for v in model],
                "model_error": [float(v) for v in cond.model_error[j]],
            })

    def _advance_thermal(self, duration: float, power: NDArray[np.float64]) -> None:
        for model, p in zip(self._thermal, power):
            model.advance(duration, float(p))
