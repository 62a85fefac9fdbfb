"""A joint's lubricant temperature from its own dissipated power, for controllers that send no motor temperature.

Without a motor temperature the only thermometer is the friction curve: the wear feature reads the lubricant
temperature ξ̂ as the one whose nominal curve fits the cycle best. That reading scatters (± 2–4 °C, single
cycles 10 °C off) and, worse, wear moves it: a wearing joint's friction reads as another temperature. A
compensation that follows ξ̂ then compensates part of the wear away, and its runs of a dozen cycles 5–7 °C off
made the KL distances cross their thresholds on healthy joints (docs/DETECTION.md).

Drives protect their motors with a thermal model driven by the dissipated power (I²t); the lubricant obeys the
same first-order law (docs/ALGORITHMS.md §1):

    τth·dξ/dt = ξamb + K·P − ξ

with P the joint's mean power over a cycle, ⟨τ·v⟩ (over a closed cycle the conservative work cancels and what
remains is dissipated, mostly by friction), τth the thermal time constant (≈ 3 h), and ξamb, K unknown per joint.
A Kalman filter on the state (ξ, ξamb, K) — linear, since P is known — predicts ξ through every cycle at its power
and every stop at zero power, and corrects it with ξ̂. A stop teaches ξamb (the joint cools towards it), a change
of power teaches K, and the prediction carries the estimate through runs of bad readings: an innovation is
clipped at :data:`CLIP` standard deviations, so no single cycle (and no wear step) moves ξ by more than a fraction
of a degree. A slow ambient drift (a hot hall) is followed through ξamb's random walk. Units: °C, seconds,
power in (torque fraction)·rad/s.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from edge_monitor.records import is_count, is_finite_number

#: Innovations are clipped at this many predicted standard deviations (Huber-style robust Kalman update).
CLIP = 2.5


@dataclass(frozen=True)
class ThermalFilterConfig:
    """``reading_std``: scatter of a friction-read temperature [°C]; ``heating_prior``/``heating_prior_std``:
    the prior of K [°C per unit power] (the simulator's and the thesis's joints: 4); ``ambient_prior_std``:
    the prior's uncertainty of ξamb around the first reading [°C]; ``ambient_drift``, ``temperature_drift``:
    random walks of ξamb and ξ [°C/√h]; ``time_constant_s``: τth [s]."""

    reading_std: float = 2.0
    heating_prior: float = 4.0
    heating_prior_std: float = 4.0
    ambient_prior_std: float = 8.0
    ambient_drift: float = 0.5
    temperature_drift: float = 0.3
    time_constant_s: float = 3.04 * 3600.0


@dataclass(frozen=True)
class ThermalObservation:
    """One cycle: ``seconds`` it ran at ``power`` [(torque fraction)·rad/s] since the previous one, and the
    friction-read lubricant temperature at its end [°C] (None: no reading this cycle)."""

    seconds: float
    power: float
    temperature: float | None


class CycleHeat:
    """The thermal model's input, gathered while a cycle runs: the mean power ⟨τ·v⟩ of its samples, and the
    seconds of running since the previous cycle closed (controller time, stops left out: they cool at zero
    power). ``add(torque, speed)`` per sample block, ``pause(seconds)`` per stop, ``close(t) -> (seconds, power)
    | None`` at the cycle's end (None for the first cycle: nothing to predict through)."""

    def __init__(self) -> None:
        self.power_sum = 0.0
        self.count = 0
        self.last_power: float | None = None     # the previous cycle's, for a cycle without finite samples
        self.last_t: float | None = None         # controller time of the previous cycle's end [s]
        self.paused = 0.0                        # seconds of stops since then

    def add(self, torque: np.ndarray, speed: np.ndarray) -> None:
        product = torque * speed
        finite = np.isfinite(product)
        self.power_sum += float(product[finite].sum())
        self.count += int(finite.sum())

    def pause(self, seconds: float) -> None:
        if math.isfinite(seconds) and seconds > 0:
            self.paused += float(seconds)

    def close(self, t: float) -> tuple[float, float] | None:
        power = self.power_sum / self.count if self.count else self.last_power
        seconds = None if self.last_t is None or not math.isfinite(t) else t - self.last_t - self.paused
        if math.isfinite(t):
            self.last_t = float(t)
        self.power_sum, self.count, self.paused = 0.0, 0, 0.0
        if power is not None:
            self.last_power = power
        if power is None or seconds is None:
            return None
        return max(0.0, seconds), power

    def state_dict(self) -> dict[str, Any]:
        return {"power_sum": self.power_sum, "count": self.count, "last_power": self.last_power,
                "last_t": self.last_t, "paused": self.paused}

    @classmethod
    def from_state(cls, state: dict[str, Any] | None) -> "CycleHeat":
        out = cls()
        if isinstance(state, dict):
            for key in ("power_sum", "last_power", "last_t", "paused"):
                value = state.get(key)
                if is_finite_number(value):
                    setattr(out, key, float(value))
            count = state.get("count")
            out.count = count if is_count(count) else 0
        return out


class LubricantThermalFilter:
    """``update(observation) -> ξ [°C] | None`` once per cycle, ``cool(seconds)`` for a stop (module docstring)."""

    def __init__(self, config: ThermalFilterConfig | None = None) -> None:
        self.config = config or ThermalFilterConfig()
        self.mean: np.ndarray | None = None          # (ξ, ξamb, K)
        self.cov: np.ndarray | None = None
        self.n_readings = 0
        self.n_clipped = 0

    @property
    def temperature(self) -> float | None:
        """The current lubricant temperature estimate [°C] (None before the first reading)."""
        return None if self.mean is None else float(self.mean[0])

    def cool(self, seconds: float) -> float | None:
        """The joint stood still for ``seconds``: predict at zero power."""
        self._predict(seconds, 0.0)
        return self.temperature

    def update(self, observation: ThermalObservation) -> float | None:
        """Predict through the cycle, correct with its reading; the estimate [°C]."""
        self._predict(observation.seconds, observation.power)
        reading = observation.temperature
        if reading is None or not math.isfinite(reading):
            return self.temperature
        if self.mean is None:
            self._start(float(reading))
        else:
            self._correct(float(reading))
        self.n_readings += 1
        return self.temperature

    def _start(self, reading: float) -> None:
        c = self.config
        self.mean = np.array([reading, reading, c.heating_prior])
        self.cov = np.diag([c.reading_std ** 2, c.ambient_prior_std ** 2, c.heating_prior_std ** 2])

    def _predict(self, seconds: float, power: float) -> None:
        if self.mean is None or self.cov is None or not (math.isfinite(seconds) and seconds > 0):
            return
        c = self.config
        p = float(power) if math.isfinite(power) else 0.0
        a = math.exp(-seconds / c.time_constant_s)
        f = np.array([[a, 1.0 - a, (1.0 - a) * p], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]])
        hours = seconds / 3600.0
        q = np.diag([c.temperature_drift ** 2 * hours, c.ambient_drift ** 2 * hours, 0.0])
        self.mean = f @ self.mean
        self.cov = f @ self.cov @ f.T + q

    def _correct(self, reading: float) -> None:
        assert self.mean is not None and self.cov is not None
        s = float(self.cov[0, 0]) + self.config.reading_std ** 2
        bound = CLIP * math.sqrt(s)
        innovation = reading - float(self.mean[0])
        if abs(innovation) > bound:
            innovation = math.copysign(bound, innovation)
            self.n_clipped += 1
        gain = self.cov[:, 0] / s
        self.mean = self.mean + gain * innovation
        self.cov = self.cov - np.outer(gain, self.cov[0, :])
        self.cov = 0.5 * (self.cov + self.cov.T)

    def reset(self) -> None:
        """Forget everything (declared maintenance: new lubricant, new friction)."""
        self.mean = self.cov = None
        self.n_readings = self.n_clipped = 0

    def state_dict(self) -> dict[str, Any]:
        return {"mean": None if self.mean is None else self.mean.tolist(),
                "cov": None if self.cov is None else self.cov.tolist(),
                "n_readings": self.n_readings, "n_clipped": self.n_clipped}

    @classmethod
    def from_state(cls, state: dict[str, Any] | None, config: ThermalFilterConfig | None = None
                   ) -> "LubricantThermalFilter":
        """Restore; a missing or malformed state starts afresh (the filter relearns within a few cycles)."""
        out = cls(config)
        if not isinstance(state, dict):
            return out
        try:
            mean = np.asarray(state["mean"], dtype=float)
            cov = np.asarray(state["cov"], dtype=float)
        except (KeyError, TypeError, ValueError):
            return out
        if mean.shape == (3,) and cov.shape == (3, 3) and np.all(np.isfinite(mean)) and np.all(np.isfinite(cov)):
            out.mean, out.cov = mean, cov
            readings, clipped = state.get("n_readings"), state.get("n_clipped")
            out.n_readings = readings if is_count(readings) else 0
            out.n_clipped = clipped if is_count(clipped) else 0
        return out
