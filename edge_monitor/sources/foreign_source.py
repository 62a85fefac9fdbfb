"""A source for a controller that does not speak our frames: a frame decoder (DBC or CiA 402) or a trace
table gives :class:`~edge_monitor.sources.samples.DecodedSamples`; a
:class:`~edge_monitor.sources.sample_stream.SampleStream` labels them with cycles and segments.

:class:`ForeignSource` has the shape of :class:`~edge_monitor.sources.ingest.Ingest` (``update`` of a
frame block → ``IngestBlock``, ``counters``, ``c``, ``e2e``, ``state_dict``/``load_state``), so the agent
takes it in its place (``Agent(config, source=…)``); :func:`open_source` builds the one a mapping file
needs. :class:`BoundSignal` is one mapped quantity resolved against a DBC or an EDS: its frame identifier,
bit field, multiplexer and conversion to the agent's unit.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Protocol

import numpy as np
from numpy.typing import NDArray

from edge_monitor.features.segmentation import PlateauConfig
from edge_monitor.sources.cycle_labels import ControllerLabels, CycleLabeller, MotionLabels, TriggerLabels
from edge_monitor.sources.ingest import IngestCounters
from edge_monitor.sources.sample_stream import SampleStream
from edge_monitor.sources.samples import DecodedSamples, IngestBlock, SourceConfig, StatusColumns
from protocol.bitfields import BitField
from protocol.e2e import E2EReceiver
from protocol.signal_mapping import CycleMapping, MappingError, SignalMapping, load_mapping

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
    length: int = 0           # bytes its frames must have (a CiA 402 TPDO's mapped length; 0: the signal's end)

    @property
    def min_dlc(self) -> int:
        """Bytes a frame must carry for this value to be in it (not zero padding)."""
        return max(self.length, self.bits.end_byte, self.mux.end_byte if self.mux is not None else 0)

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
        return ControllerLabels(rate_hz)
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
    joints: frozenset[int] | None = None     # the config's joints (None: every mapped joint); others counted, dropped

    def __post_init__(self) -> None:
        if self.decoder is not None:
            self.c = self.decoder.c
        log.info("cycles from the %s", self.stream.labeller.method)

    def update(self, ids: NDArray, data: NDArray, dlc: NDArray, timestamps: NDArray) -> IngestBlock:
        if self.decoder is None:
            raise TypeError("this source reads tables, not frames: use update_samples")
        return self._kept(self.stream.update(self.decoder.decode(ids, data, dlc, timestamps)))

    def update_samples(self, decoded: DecodedSamples) -> IngestBlock:
        return self._kept(self.stream.update(decoded))

    def flush(self) -> IngestBlock:
        return self._kept(self.stream.flush())

    def _kept(self, block: IngestBlock) -> IngestBlock:
        """``block`` without the joints the config does not monitor (their samples counted in ``joint_filtered``);
        filtered after the cycles are found, which may follow a joint not monitored."""
        if self.joints is not None:
            for run in block.runs:
                for joint in [j for j in run.samples if j not in self.joints]:
                    self.c.joint_filtered += int(run.samples.pop(joint).tick.size)
                for joint in [j for j in run.joint_status if j not in self.joints]:
                    del run.joint_status[joint]
        return block

    def counters(self) -> dict[str, Any]:
        return {**self.c.__dict__, "samples_dropped": dict(self.stream.dropped),
                "cycle_finding": self.stream.counters()}

    def state_dict(self) -> dict[str, Any]:
        """The cycle numbering (flat integers, as the agent's state validation expects): a restarted agent
        numbers the cycles it finds after the ones it published."""
        return self.stream.labeller.state_dict()

    def load_state(self, state: dict[str, Any]) -> None:
        self.stream.labeller.load_state(state)


def decoder_for(mapping: SignalMapping) -> FrameDecoder | None:
    """The frame decoder of a mapping (None for trace tables)."""
    if mapping.kind == "dbc":
        from edge_monitor.sources.dbc_source import DbcDecoder
        return DbcDecoder(mapping)
    if mapping.kind == "cia402":
        from edge_monitor.sources.cia402_source import Cia402Decoder
        return Cia402Decoder(mapping)
    return None


def open_source(mapping: SignalMapping | str | Path, config: SourceConfig) -> ForeignSource:
    """A source for ``mapping`` (a path or a loaded mapping) at the tick rate ``config.rate_hz`` (the
    agent's config after :func:`~edge_monitor.pipeline.agent_config.config_for`); raises MappingError
    with the fix."""
    m = mapping if isinstance(mapping, SignalMapping) else load_mapping(mapping)
    labeller = make_labeller(m.cycles, config.rate_hz, config.segmentation)
    stream = SampleStream(labeller, config.rate_hz, int(m.cycles.reference_joint or 0))
    return ForeignSource(stream, decoder_for(m), joints=monitored_joints(m, config.joints))


def monitored_joints(mapping: SignalMapping, configured: tuple[int, ...] | None) -> frozenset[int] | None:
    """The mapped joints the config's ``joints`` keeps (None: every mapped joint); MappingError when it keeps none,
    a warning for configured joints the mapping does not map (the false-alarm budget is split over the config's)."""
    if configured is None:
        return None
    mapped = set(mapping.joints)
    kept = frozenset(configured) & mapped
    if not kept:
        raise MappingError(f"{mapping.where('joint')}: the agent's config monitors joints {sorted(configured)}, the "
                           f"mapping maps joints {sorted(mapped)}: none in common; fix the config's joints "
                           "(or omit it to monitor every mapped joint) or the mapping")
    if missing := sorted(set(configured) - mapped):
        log.warning("%s: the agent's config monitors joints %s, which the mapping does not map: they are not "
                    "monitored", mapping.where("joint"), missing)
    return kept


def short_frames(bounds: list[BoundSignal], ids: NDArray[np.int64], dlc: NDArray[np.int64]) -> NDArray[np.bool_]:
    """Frames shorter than what a mapped value in them needs (a TPDO shorter than its PDO mapping, a DBC
    frame cut before a signal): decoding them would read zero padding as values, so they are dropped."""
    need: dict[int, int] = {}
    for b in bounds:
        need[b.frame_id] = max(need.get(b.frame_id, 0), b.min_dlc)
    short = np.zeros(ids.size, dtype=bool)
    for frame_id, length in need.items():
        short |= (ids == frame_id) & (dlc < length)
    return short


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
