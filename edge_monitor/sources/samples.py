"""The sample interface between the sources and the pipeline: what every source hands the agent.

Everything above the sources (cycle assembly, features, detectors, sinks) works on per-joint samples:
controller time (ticks at the agent's ``rate_hz``), motor speed [rad/s, motor side], motor torque [fraction
of the joint's reference torque T_ref] and the segment code in force (speed level k is segment k + 1, 0 a
transition, 200 production motion, −1 unknown); per joint, where the controller has them, its load
estimate μl, σl [fraction of T_ref] and motor temperature [°C], one entry per status frame; and the cycle
they belong to. A source produces an :class:`IngestBlock` of :class:`CycleRun` s, which
``Agent.update_ingested`` takes; a source of frames has the shape of :class:`SampleSource` and the agent
takes it whole (``Agent(config, source=…)``). The sources are listed in :mod:`edge_monitor.sources`.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any, Protocol

import numpy as np
from numpy.typing import NDArray

if TYPE_CHECKING:
    from edge_monitor.features.segmentation import PlateauConfig
    from protocol.e2e import E2EReceiver


@dataclass
class JointSamples:
    """Usable samples of one joint within one cycle run of a block, in stream order."""

    tick: NDArray[np.int64]
    speed: NDArray[np.float64]      # rad/s, motor side
    torque: NDArray[np.float64]     # fraction of max. joint torque
    segment: NDArray[np.int64]      # controller segment code in force (-1: unknown)


@dataclass(frozen=True)
class JointStatusBlock:
    """JointStatus frames of one joint in stream order: the controller's load estimate μl and its σl
    (fraction of max. torque) and the motor temperature [°C], one entry per frame (NaN: not sent)."""

    load_estimate: NDArray[np.float64]
    load_std: NDArray[np.float64]
    motor_temperature: NDArray[np.float64]


@dataclass
class CycleRun:
    """A maximal run of rows of a block under one controller cycle number (``None``: unknown)."""

    cycle: int | None
    samples: dict[int, JointSamples]
    joint_status: dict[int, JointStatusBlock]
    starts_at_boundary: bool | None = None              # first run of a cycle: was its start seen?
    previous_cut: bool = False                          # entered by a controller restart: the cycle
                                                        # before it ended early (its end is unknown)
    last_time: float | None = None                      # timestamp of the run's last frame (bus or log) [s]
    rows: int = 0                                       # frames of the block in this run


@dataclass
class IngestBlock:
    runs: list[CycleRun] = field(default_factory=list)


@dataclass
class JointColumns:
    """Decoded, not yet labelled samples of one joint: time [s], speed [rad/s], torque [fraction]."""

    time: NDArray[np.float64]
    speed: NDArray[np.float64]
    torque: NDArray[np.float64]


@dataclass
class StatusColumns:
    """Decoded per-joint status values with their times [s]; NaN where a quantity was not in the frame."""

    time: NDArray[np.float64]
    load: NDArray[np.float64]
    temperature: NDArray[np.float64]


@dataclass
class DecodedSamples:
    """One block of a foreign source, decoded and converted to the agent's units but without cycle labels.
    ``marks``: the cycle-mark signals the mapping names (``cycle``, ``segment``, ``trigger``), each
    ``(time [s], value)``."""

    joints: dict[int, JointColumns] = field(default_factory=dict)
    status: dict[int, StatusColumns] = field(default_factory=dict)
    marks: dict[str, tuple[NDArray[np.float64], NDArray[np.float64]]] = field(default_factory=dict)


class SourceConfig(Protocol):
    """What a source reads of the agent's config (``AgentConfig`` has it): the tick rate [Hz] sample times
    are converted to, the joints to keep (None: all), the plateau settings (cycles found from the motion)."""

    @property
    def rate_hz(self) -> float: ...
    @property
    def joints(self) -> tuple[int, ...] | None: ...
    @property
    def segmentation(self) -> PlateauConfig: ...


class FrameCounters(Protocol):
    """A source's counters (a dataclass: its fields go to the health record); ``frames_total`` at least."""

    frames_total: int


class SampleSource(Protocol):
    """A source of frames as the agent takes it (``Agent(config, source=…)``): a block of frames in
    (``ids`` (n,), ``data`` (n, 8) uint8, ``dlc`` (n,), ``timestamps`` [s]), labelled samples out; its
    counters and E2E statistics for the health record; the cycle numbering in the agent's state (flat JSON).
    A source that holds samples back (cycles found from the motion) also has ``flush() -> IngestBlock``."""

    @property
    def c(self) -> FrameCounters: ...
    @property
    def e2e(self) -> E2EReceiver: ...
    def update(self, ids: NDArray, data: NDArray, dlc: NDArray, timestamps: NDArray) -> IngestBlock: ...
    def counters(self) -> dict[str, Any]: ...
    def state_dict(self) -> dict[str, Any]: ...
    def load_state(self, state: dict[str, Any]) -> None: ...
