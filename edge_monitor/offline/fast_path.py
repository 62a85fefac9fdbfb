"""The agent on the simulator's cycle-level mode: every algorithm after ingest runs for real, without
encoding, checking and decoding frames (studies of 10⁵ cycles; docs/DETECTION.md).

:class:`CycleFeeder` hands each simulated cycle, labelled by the source
:class:`~edge_monitor.sources.cycle_arrays.CycleArraySource` exactly as the ingest labels frames, to
:meth:`Agent.update_ingested`. With the same seed the per-cycle quantities equal those of
``sim-controller record`` + ``edge-monitor replay`` (tests/test_fast_path.py).
"""

from __future__ import annotations

from typing import Any, Iterable, Iterator, Mapping

from edge_monitor.config import config_from_mapping
from edge_monitor.pipeline.agent import Agent
from edge_monitor.records import Symptom
from edge_monitor.sources.cycle_arrays import CycleArraySource
from sim_controller.config import SimConfig
from sim_controller.cycle_mode import CycleSignals, cycle_signals, without_motor_temperature

#: The per-cycle values the agent's detectors watch (before their log transform).
DETECTOR_INPUTS = ("wear_score", "kl_raw", "kl_weighted")
#: Where each is in a symptom record: (part, key).
DETECTOR_FIELDS = {"wear_score": ("wear", "score"), "kl_raw": ("kl", "raw"), "kl_weighted": ("kl", "weighted")}

#: (joint, cycle, values, truth): a row of :func:`detector_inputs_with_truth`.
Row = tuple[int, int, dict[str, float], dict[str, Any]]


class CycleFeeder:
    """Feeds an :class:`Agent` with :class:`CycleSignals` (see the module docstring)."""

    def __init__(self, agent: Agent) -> None:
        self.agent = agent
        self.source = CycleArraySource()

    def update(self, cycle: CycleSignals) -> list[Symptom]:
        """One simulated cycle; returns the symptoms it completed (those of the previous cycle)."""
        return self.agent.update_ingested(self.source.update(cycle))

    def finish(self) -> list[Symptom]:
        """End of the run: close the last cycle."""
        return self.agent.finish(close_open_cycle=True)


def run_cycles(agent: Agent, cycles: Iterable[CycleSignals]) -> Iterator[Symptom]:
    """Every symptom of the agent over ``cycles`` (the last cycle closed at the end)."""
    feeder = CycleFeeder(agent)
    for cycle in cycles:
        yield from feeder.update(cycle)
    yield from feeder.finish()


def detector_inputs(config: SimConfig, settings: Mapping[str, Any] | None = None
                    ) -> Iterator[tuple[int, int, dict[str, float]]]:
    """``(joint, cycle, {wear_score, kl_raw, kl_weighted})`` of every cycle of the simulated robot once its
    joint has learned its model and KL nominal; the agent at its shipped defaults (or with ``settings``,
    agent config tables merged over them) with the detectors off (studies run the detectors themselves
    on these values)."""
    for joint, cycle, values, _truth in detector_inputs_with_truth(config, settings):
        yield joint, cycle, values


def detector_inputs_with_truth(config: SimConfig, settings: Mapping[str, Any] | None = None, *,
                               motor_temperature: bool = True) -> Iterator[Row]:
    """:func:`detector_inputs` with the simulator's ground truth of each joint-cycle (lubricant
    temperature [°C], load, wear, …: ``CycleSignals.truth``). ``motor_temperature=False``: the cycles as
    a controller that sends none sends them, and each row's values also hold ``friction_temperature``,
    the lubricant temperature [°C] the wear estimate read from the friction (the detectors follow it)."""
    tables: dict[str, Any] = {key: dict(value) for key, value in (settings or {}).items()}
    tables["decision"] = {**tables.get("decision", {}), "enabled": False}
    feeder = CycleFeeder(Agent(config_from_mapping(tables)))
    truth: dict[tuple[int, int], dict[str, Any]] = {}
    fields = dict(DETECTOR_FIELDS)
    if not motor_temperature:
        fields["friction_temperature"] = ("wear", "temperature")

    def rows(symptoms: list[Symptom]) -> Iterator[Row]:
        for symptom in symptoms:
            record = symptom.to_dict()
            joint, cycle = int(record["joint"]), int(record["cycle"])
            known = truth.pop((cycle, joint), {})
            values = _record_values(record, fields)
            if values is not None:
                yield joint, cycle, values, known

    for signals in cycle_signals(config):
        truth.update({(signals.cycle, j): t for j, t in enumerate(signals.truth)})
        yield from rows(feeder.update(signals if motor_temperature else without_motor_temperature(signals)))
    yield from rows(feeder.finish())


def _record_values(record: Mapping[str, Any], fields: Mapping[str, tuple[str, str]]) -> dict[str, float] | None:
    """The symptom record's values of ``fields`` (name: (part, key)), or None while one is missing (the
    joint's model or its KL nominal still learning)."""
    values: dict[str, float] = {}
    for name, (part, key) in fields.items():
        value = (record.get(part) or {}).get(key)
        if value is None:
            return None
        values[name] = float(value)
    return values
