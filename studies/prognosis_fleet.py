"""The simulated fleet the prognosis is validated on: wearing joints under laws the trend model does not
assume, and healthy joints, through a plant's week, with every per-cycle input of the prognosis recorded
(docs/PROGNOSIS.md).

Each robot is one simulator seed at its defaults (6 joints, ±8 % individual variation, the thermal model,
the load spread) on the packaged ``plant_week`` timeline (daily cold starts, shift changes, overnight
stops, product B's heavier load from cycle 2 000). A wearing robot gives each joint one law; the law's
onset and life (cycles from the onset to the critical wear 35) are drawn per joint from the seed:

* ``linear``       a ramp 0 → 60;
* ``power``        0 → 60 as x^p, p ~ U(1.6, 2.6) (accelerating);
* ``exponential``  0 → 60 as (e^{s·x} − 1)/(e^{s} − 1), s ~ U(2, 3.5) (accelerating faster);
* ``step_ramp``    a step to 8 … 14 at the onset, then a slow ramp;
* ``rate_change``  a slow ramp to 6 … 12 over 40 … 60 % of the life, then a faster one.

:func:`robot_series` runs one robot through the whole agent (its shipped defaults, detectors on) on the
fast path and keeps, per joint and cycle, what the agent's prognosis is fed (:class:`CycleRow`) next to
the simulator's true wear.
"""

from __future__ import annotations

import logging
import math
import time
from dataclasses import asdict, dataclass
from typing import Any, Iterator

import numpy as np

from edge_monitor.config import config_from_mapping
from edge_monitor.offline.fast_path import CycleFeeder
from edge_monitor.pipeline.agent import Agent
from edge_monitor.records import Symptom
from joint_model import CRITICAL_WEAR
from sim_controller.config import SimConfig
from sim_controller.controller import Controller
from sim_controller.cycle_mode import cycle_signals
from sim_controller.scenario import scenario_config
from sim_controller.wear_scenarios import WearEvent, WearProfile

log = logging.getLogger(__name__)

LAWS = ("linear", "power", "exponential", "step_ramp", "rate_change")
#: The plant timeline the fleet runs on (sim_controller/scenarios/plant_week.toml).
SCENARIO = "plant_week"
#: Wear at the end of every law's events (past the critical 35, so that each joint crosses it).
FINAL_WEAR = 60.0
#: Onset and life ranges [cycles]; cycles run after the last joint of a robot reaches critical wear.
ONSET = (150, 400)
LIFE = (900, 1900)
AFTER_END = 40


@dataclass(frozen=True)
class JointLaw:
    """One joint's wear law: its name, the simulator's events, the onset and the true end of life
    (the first cycle at critical wear, from the events themselves)."""

    law: str
    onset: int
    life: int
    events: tuple[WearEvent, ...]

    @property
    def end_of_life(self) -> int:
        """First cycle whose true wear is ≥ the critical wear."""
        profile = WearProfile(events=self.events)
        cycle = self.onset
        while profile.wear(cycle) < CRITICAL_WEAR:
            cycle += 1
        return cycle

    def to_dict(self) -> dict[str, Any]:
        return {"law": self.law, "onset": self.onset, "life": self.life, "end_of_life": self.end_of_life,
                "events": [e.to_dict() for e in self.events]}


def joint_law(law: str, onset: int, life: int, shape: float) -> JointLaw:
    """The events of ``law`` starting at ``onset`` that reach the critical wear ``life`` cycles later;
    ``shape`` in [0, 1) picks the law's free parameter within its range (module docstring)."""
    critical = CRITICAL_WEAR
    events: tuple[WearEvent, ...]
    if law == "linear":
        events = (WearEvent("ramp", onset, onset + round(life * FINAL_WEAR / critical), 0.0, FINAL_WEAR),)
    elif law == "power":
        p = 1.6 + shape
        span = round(life / (critical / FINAL_WEAR) ** (1 / p))
        events = (WearEvent("power", onset, onset + span, 0.0, FINAL_WEAR, exponent=p),)
    elif law == "exponential":
        s = 2.0 + 1.5 * shape
        span = round(life * s / math.log1p(critical / FINAL_WEAR * math.expm1(s)))
        events = (WearEvent("exponential", onset, onset + span, 0.0, FINAL_WEAR, tau=span / s),)
    elif law == "step_ramp":
        height = 8.0 + 6.0 * shape
        span = round(life * (FINAL_WEAR - height) / (critical - height))
        events = (WearEvent("step", onset, to=height), WearEvent("ramp", onset, onset + span, height, FINAL_WEAR))
    elif law == "rate_change":
        change, level = onset + round(life * (0.4 + 0.2 * shape)), 6.0 + 6.0 * shape
        span = round((onset + life - change) * (FINAL_WEAR - level) / (critical - level))
        events = (WearEvent("ramp", onset, change, 0.0, level),
                  WearEvent("ramp", change, change + span, level, FINAL_WEAR))
    else:
        raise ValueError(f"law: unknown {law!r}; use one of {LAWS}")
    return JointLaw(law, onset, life, events)


def robot_laws(seed: int, joints: int = 6) -> list[JointLaw]:
    """Each joint's law (``LAWS`` in turn, from the ``seed % 5``-th: consecutive seeds spread them evenly),
    onset, life and shape, drawn from ``seed``."""
    rng, first_law = np.random.default_rng([seed, 48]), seed % len(LAWS)
    out = []
    for j in range(joints):
        onset, life, shape = int(rng.integers(*ONSET)), int(rng.integers(*LIFE)), float(rng.random())
        out.append(joint_law(LAWS[(first_law + j) % len(LAWS)], onset, life, shape))
    return out


def robot_config(seed: int, laws: list[JointLaw] | None, cycles: int | None = None) -> SimConfig:
    """The simulator's config of one robot: the plant week, its joints' laws (None: healthy), as many
    cycles as its last joint needs to reach critical wear (or ``cycles``)."""
    fields: dict[str, Any] = {"seed": seed, "joints": 6 if laws is None else len(laws)}
    if laws is not None:
        fields["wear"] = tuple(WearProfile(events=law.events) for law in laws)
        fields["cycles"] = cycles or max(law.end_of_life for law in laws) + AFTER_END
    elif cycles is not None:
        fields["cycles"] = cycles
    return scenario_config(SCENARIO, fields)


def known_model_settings(config: SimConfig) -> dict[str, Any]:
    """Agent settings that give every joint its true friction model (the simulator's individually varied
    parameters, wear coefficients included) instead of the one it would learn: the estimator's error
    without any model error, for the prognosis's error budget."""
    joints = Controller(config).joints
    return {"model": {"enabled": False},
            "joint": {str(s.joint): {"friction": s.friction.to_dict()} for s in joints}}


@dataclass(frozen=True)
class CycleRow:
    """What the prognosis is fed in one cycle of one joint, with the truth: ``t`` controller time at the
    cycle's end [s]; ``estimate``/``std`` the symptom's ``wear.estimate``/``wear.std``; ``alarm`` any of
    the joint's detectors latched; ``learning`` the joint still learns its friction model; ``partial``;
    ``posterior_mean`` the symptom's ``wear.posterior_mean``; ``temperature`` the temperature the KL
    compensation used (``kl.temperature.value``) [°C] (both None in inputs kept before they were recorded)."""

    cycle: int
    t: float
    wear: float
    estimate: float | None
    std: float | None
    alarm: bool
    learning: bool
    partial: bool
    posterior_mean: float | None = None
    temperature: float | None = None

    def to_list(self) -> list[Any]:
        return list(asdict(self).values())

    @classmethod
    def from_list(cls, row: list[Any]) -> "CycleRow":
        return cls(*row)


def symptom_row(symptom: Symptom, truth: float) -> CycleRow:
    """The :class:`CycleRow` of one symptom (``truth``: the simulator's wear of that joint-cycle)."""
    record = symptom.to_dict()
    wear = record.get("wear") or {}
    learning = "friction model" in (record.get("reasons") or {}).get("kl", "")
    return CycleRow(int(record["cycle"]), float(record["t"]), truth, wear.get("estimate"), wear.get("std"),
                    bool(record["alarm"]), learning, bool(record.get("partial", False)), wear.get("posterior_mean"),
                    ((record.get("kl") or {}).get("temperature") or {}).get("value"))


def robot_series(config: SimConfig, settings: dict[str, Any] | None = None) -> dict[int, list[CycleRow]]:
    """Per joint, the :class:`CycleRow` of every cycle of the robot ``config`` describes, through the
    agent at its shipped defaults (``settings``: agent TOML tables over them) on the fast path."""
    feeder = CycleFeeder(Agent(config_from_mapping(settings or {})))
    truth: dict[tuple[int, int], float] = {}
    out: dict[int, list[CycleRow]] = {}
    started = time.monotonic()

    def take(symptoms: list[Symptom]) -> None:
        for s in symptoms:
            out.setdefault(s.joint, []).append(symptom_row(s, truth.pop((s.cycle, s.joint), math.nan)))

    for signals in cycle_signals(config):
        truth.update({(signals.cycle, j): float(t["wear"]) for j, t in enumerate(signals.truth)})
        take(feeder.update(signals))
        if signals.cycle % 200 == 199:
            log.info("seed %d: cycle %d/%d, %.0f s", config.seed, signals.cycle + 1, config.cycles,
                     time.monotonic() - started)
    take(feeder.finish())
    return out


def rows_of(series: dict[int, list[CycleRow]]) -> Iterator[tuple[int, list[CycleRow]]]:
    """``(joint, rows)`` in joint order."""
    for joint in sorted(series):
        yield joint, series[joint]
