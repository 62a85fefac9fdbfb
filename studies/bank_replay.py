"""The agent's detectors over kept series: one joint's rows (:mod:`studies.series`) fed to a
:class:`~edge_monitor.pipeline.detectors.DetectorBank` as the agent feeds it — the cycle's motor temperature
first (thermal settling, holds), then the detector inputs — one step per row.

Every study that runs only the detectors goes through :func:`replay_bank`. Between two steps the caller may
act on the bank as an operator would (``bank.detectors[q].acknowledge()``, ``.reset()``); ``values`` may
change what a step feeds (e.g. a shift to the edge of the null), read lazily, so it sees what the caller
did after the previous step.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, Callable, Iterable, Iterator

import numpy as np

from edge_monitor.pipeline.decision_config import DecisionConfig
from edge_monitor.pipeline.detectors import DetectorBank
from edge_monitor.records import Alarm, Decision
from edge_monitor.stats.sequential_detector import SequentialDetector

#: A kept row: ``cycle``, the detector inputs, ``motor_temperature`` [°C] and the simulator's truth.
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
                values: Callable[[Row], Row] | None = None) -> Iterator[BankStep]:
    """``bank`` over ``rows`` in order, one :class:`BankStep` each (see the module docstring); a row without a
    ``cycle`` is numbered by its position. ``joint`` and ``robot`` only label the alarms."""
    for position, row in enumerate(rows):
        cycle = int(row.get("cycle", position))
        bank.observe_temperature(row.get("motor_temperature"))
        decisions, raised = bank.update(values(row) if values is not None else row, robot, joint, cycle)
        yield BankStep(cycle, row, decisions, raised)


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
