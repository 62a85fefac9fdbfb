"""A source for a controller that does not speak our frames: a frame decoder (DBC or CiA 402) or a trace
table gives :class:`~edge_monitor.pipeline.samples.DecodedSamples`; a
:class:`~edge_monitor.pipeline.sample_stream.SampleStream` labels them with cycles and segments.

:class:`ForeignSource` has the shape of :class:`~edge_monitor.pipeline.ingest.Ingest` (``update`` of a
frame block → ``IngestBlock``, ``counters``, ``c``, ``e2e``, ``state_dict``/``load_state``), so the agent
takes it in its place (``Agent(config, source=…)``). :class:`BoundSignal` is one mapped quantity resolved
against a DBC or an EDS: its frame identifier, bit field, multiplexer and conversion to the agent's unit.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, field
from typing import Any, Protocol

import numpy as np
from numpy.typing import NDArray

from edge_monitor.features.segmentation import PlateauConfig
from edge_monitor.pipeline.cycle_labels import ControllerLabels, CycleLabeller, MotionLabels, TriggerLabels
from edge_monitor.pipeline.ingest import IngestCounters
from edge_monitor.pipeline.sample_stream import SampleStream
from edge_monitor.pipeline.samples import DecodedSamples, IngestBlock, StatusColumns
from protocol.bitfields import BitField
from protocol.e2e import E2EReceiver
from protocol.signal_mapping import CycleMapping

log = logging.getLogger(__name__)


@dataclass
class ForeignCounters(IngestCounters):
    """Ingest counters plus what foreign sources drop: samples of a drive not in "operation enabled"."""

    not_enabled: int = 0


@dataclass(frozen=True)
class BoundSignal:
    """A mapped quantity on the wire: agent value = field value · factor + offset, in frames ``frame_id``
    (and, for a multiplexed signal, only where ``mux`` reads ``mux_value``)."""

    name: str
    frame_id: int
    bits: BitField
    factor: float = 1.0
    offset: float = 0.0
    mux: BitField | None = None
    mux_value: int = 0

    def rows(self, ids: NDArray[np.int64], data: NDArray[np.uint8], usable: NDArray[np.bool_]) -> NDArray[np.int64]:
        mask = usable & (ids == self.frame_id)
        if self.mux is not None and mask.any():
            mask[mask] = self.mux.raw(data[mask]).astype(np.int64) == self.mux_value
        return np.flatnonzero(mask)

    def values(self, data: NDArray[np.uint8]) -> NDArray[np.float64]:
        return self.bits.decode(data) * self.factor + self.offset


class FrameDecoder(Protocol):
    c: ForeignCounters
    def decode(self, ids: NDArray, data: NDArray, dlc: NDArray, timestamps: NDArray) -> DecodedSamples: ...
    def describe(self) -> dict[int, dict[str, str]]: ...


def make_labeller(cycles: CycleMapping, rate_hz: float, plateau: PlateauConfig) -> CycleLabeller:
    if cycles.source == "controller":
        return ControllerLabels()
    if cycles.source == "trigger":
        return TriggerLabels(cycles.trigger_value)
    return MotionLabels(cycles.speeds, rate_hz, plateau)


@dataclass
class ForeignSource:
    """A decoder (or none: trace tables) and the sample stream that labels its samples."""

    stream: SampleStream
    decoder: FrameDecoder | None = None
    c: ForeignCounters = field(default_factory=ForeignCounters)
    e2e: E2EReceiver = field(default_factory=E2EReceiver)     # unused: keeps the agent's health shape

    def __post_init__(self) -> None:
        if self.decoder is not None:
            self.c = self.decoder.c
        log.info("cycles from the %s", self.stream.labeller.method)

    def update(self, ids: NDArray, data: NDArray, dlc: NDArray, timestamps: NDArray) -> IngestBlock:
        if self.decoder is None:
            raise TypeError("this source reads tables, not frames: use update_samples")
        return self.stream.update(self.decoder.decode(ids, data, dlc, timestamps))

    def update_samples(self, decoded: DecodedSamples) -> IngestBlock:
        return self.stream.update(decoded)

    def flush(self) -> IngestBlock:
        return self.stream.flush()

    def counters(self) -> dict[str, Any]:
        return {**self.c.__dict__, "samples_dropped": dict(self.stream.dropped),
                "cycle_finding": self.stream.counters()}

    def state_dict(self) -> dict[str, Any]:
        """The cycle numbering (flat integers, as the agent's state validation expects): a restarted agent
        numbers the cycles it finds after the ones it published."""
        return self.stream.labeller.state_dict()

    def load_state(self, state: dict[str, Any]) -> None:
        self.stream.labeller.load_state(state)


def take(bound: BoundSignal, ids: NDArray[np.int64], data: NDArray[np.uint8], times: NDArray[np.float64],
         usable: NDArray[np.bool_]) -> tuple[NDArray[np.int64], NDArray[np.float64], NDArray[np.float64]]:
    """Rows, times and agent values of ``bound`` in a block."""
    rows = bound.rows(ids, data, usable)
    return rows, times[rows], bound.values(data[rows])


def status_columns(bounds: dict[str, BoundSignal], ids: NDArray[np.int64], data: NDArray[np.uint8],
            times: NDArray[np.float64], usable: NDArray[np.bool_], used: NDArray[np.bool_]) -> StatusColumns:
    """Load and temperature of one joint, one entry per frame that carries either (NaN: the other)."""
    picked = {q: take(b, ids, data, times, usable) for q, b in bounds.items()}
    rows = np.unique(np.concatenate([p[0] for p in picked.values()])) if picked else np.empty(0, np.int64)
    used[rows] = True
    columns = {}
    for q in ("load", "temperature"):
        col = np.full(rows.size, np.nan)
        if q in picked:
            col[np.searchsorted(rows, picked[q][0])] = picked[q][2]
        columns[q] = col
    return StatusColumns(times[rows], columns["load"], columns["temperature"])
