"""The agent's detectors over kept series: one joint's rows (:mod:`studies.series`) fed to a
:class:`~edge_monitor.pipeline.detectors.DetectorBank` as the agent feeds it — the cycle's motor temperature
first (thermal settling, holds; on a robot without one the lubricant temperature read from the friction), then
the detector inputs — one step per row.

Every study that runs only the detectors goes through :func:`replay_bank`. Between two steps the caller may
act on the bank as an operator would (``bank.detectors[q].acknowledge()``, ``.reset()``); ``values`` may
change what a step feeds (e.g. a shift to the edge of the null), read lazily, so it sees what the caller
did after the previous step.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, Callable, Iterable, Iterator, Mapping

import numpy as np

from edge_monitor.pipeline.decision_config import DecisionConfig
from edge_monitor.pipeline.detectors import DetectorBank
from edge_monitor.pipeline.nominal_temperature import FRICTION_TEMPERATURE, MOTOR_TEMPERATURE
from edge_monitor.records import Alarm, Decision
from edge_monitor.stats.sequential_detector import SequentialDetector

#: A kept row: ``cycle``, the detector inputs, ``motor_temperature`` [°C] (on a robot without one,
#: ``friction_temperature``) and the simulator's truth.
Row = dict[str, Any]


@dataclass(frozen=True)
class BankStep:
    """One cycle of a replay: its number, the row fed, the decision per quantity, the alarms it raised."""

    cycle: int
    row: Row
    decisions: dict[str, Decision]
    raised: list[Alarm]


def new_bank(decision: DecisionConfig) -> DetectorBank:
    """A joint's detectors as the agent builds them for ``decision`` (the ``[decision]`` table)."""
    return DetectorBank(decision, {})


def replay_bank(bank: DetectorBank, rows: Iterable[Row], joint: int = 0, robot: str = "study",
                values: Callable[[Row], Row] | None = None,
                pauses: Mapping[int, float] | None = None) -> Iterator[BankStep]:
    """``bank`` over ``rows`` in order, one :class:`BankStep` each (see the module docstring); a row without a
    ``cycle`` is numbered by its position. ``joint`` and ``robot`` only label the alarms. ``pauses``: the
    seconds the robot stood still before a cycle (the agent sees them as a gap in the samples)."""
    for position, row in enumerate(rows):
        cycle = int(row.get("cycle", position))
        if pauses and pauses.get(cycle, 0.0) > 0:
            bank.pause(pauses[cycle])
        bank.observe_temperature(*detectors_temperature(row))
        decisions, raised = bank.update(values(row) if values is not None else row, robot, joint, cycle)
        yield BankStep(cycle, row, decisions, raised)


def detectors_temperature(row: Row) -> tuple[float | None, str]:
    """The temperature [°C] a row's detectors follow and what it is: its motor temperature, or on a robot without
    one the lubricant temperature read from the friction (as edge_monitor.pipeline.temperature_source picks)."""
    motor = row.get("motor_temperature")
    return (motor, MOTOR_TEMPERATURE) if motor is not None else (row.get("friction_temperature"), FRICTION_TEMPERATURE)


def standard_units(detector: SequentialDetector, value: float) -> float:
    """A scalar ``value`` (in the units the detector watches) in the standard units of the nominal it
    monitors with: its steady stage's transform, if any, then the learned mean and standard deviation;
    NaN while it learns."""
    density = detector.density
    if density is None:
        return math.nan
    x = np.array([[value]])
    if detector.transform is not None:
        x = detector.transform.apply(x)
    return (float(np.ravel(x)[0]) - float(density.means[0, 0])) / float(np.sqrt(np.ravel(density.cov)[0]))
