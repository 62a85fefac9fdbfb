"""Which source feeds the agent: our native frames (no mapping), or a mapping file's DBC / CiA 402 drives /
trace tables (:func:`open_source`). The agent config's ``rate_hz`` is the tick rate the samples' times are
converted to; a mapping that states ``rate_hz`` overrides it."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

from edge_monitor.pipeline.agent_config import AgentConfig
from edge_monitor.pipeline.foreign_source import ForeignSource, FrameDecoder, make_labeller
from edge_monitor.pipeline.sample_stream import SampleStream
from protocol.signal_mapping import SignalMapping, load_mapping


def decoder_for(mapping: SignalMapping) -> FrameDecoder | None:
    """The frame decoder of a mapping (None for trace tables)."""
    if mapping.kind == "dbc":
        from edge_monitor.pipeline.dbc_source import DbcDecoder
        return DbcDecoder(mapping)
    if mapping.kind == "cia402":
        from edge_monitor.pipeline.cia402_source import Cia402Decoder
        return Cia402Decoder(mapping)
    return None


def config_for(config: AgentConfig, mapping: SignalMapping) -> AgentConfig:
    """The agent config a mapping needs: its rate, its joints, and (cycles from a trigger) the designed
    speeds as the plateau levels (the trigger marks the cycle, not the levels)."""
    out = config
    if mapping.rate_hz is not None:
        out = replace(out, rate_hz=mapping.rate_hz)
    if mapping.cycles.source == "trigger" and not out.segmentation.speeds:
        out = replace(out, segmentation=replace(out.segmentation, speeds=mapping.cycles.speeds))
    return out


def open_source(mapping: SignalMapping | str | Path, config: AgentConfig) -> ForeignSource:
    """A source for ``mapping`` (a path or a loaded mapping); raises MappingError with the fix."""
    m = mapping if isinstance(mapping, SignalMapping) else load_mapping(mapping)
    labeller = make_labeller(m.cycles, config.rate_hz, config.segmentation)
    stream = SampleStream(labeller, config.rate_hz, int(m.cycles.reference_joint or 0))
    return ForeignSource(stream, decoder_for(m))
