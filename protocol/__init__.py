"""Shared wire format: frame catalogue, scaling, E2E protection, DBC, links (docs/PROTOCOL.md).

Modules: ``crc`` (CRC-8H2F: crccheck scalar, numpy block), ``frames`` (catalogue, encoders,
decoders, block codecs), ``e2e`` (receiver check state machine), ``dbc`` (DBC rendered from the
catalogue, loaded via cantools), ``links`` (python-can buses from link strings, log files, pty
pair, vcan detection), ``slcan_fast`` (chunked slcan reader), ``bench_micro`` (micro-benchmarks),
``console`` (conventions of both command-line tools: verbosity, exit codes, -i/-c/-b, progress bars).
"""

from importlib import metadata as _metadata

from protocol.crc import crc8h2f, crc8h2f_block
from protocol.e2e import E2EReceiver, E2EState, E2EStatus
from protocol.frames import (
    CATALOGUE,
    ControllerStatus,
    DecodedBlock,
    DecodeError,
    DecodeErrorKind,
    FrameKind,
    JointStatus,
    Mode,
    MotorState,
    SignalRole,
    decode,
    decode_block,
    decode_message,
    frame_crc,
    messages_to_arrays,
    to_message,
)

#: Installed distribution that ships the simulator, the protocol and the agent (one version for all).
DISTRIBUTION = "joint-wear-monitor"


def package_version() -> str:
    """The installed version of the distribution ("unknown" when run from an uninstalled checkout)."""
    try:
        return _metadata.version(DISTRIBUTION)
    except _metadata.PackageNotFoundError:
        return "unknown"


__all__ = [
    "CATALOGUE", "ControllerStatus", "DecodeError", "DecodeErrorKind", "DecodedBlock", "E2EReceiver",
    "E2EState", "E2EStatus", "FrameKind", "JointStatus", "Mode", "MotorState", "SignalRole", "crc8h2f",
    "DISTRIBUTION", "crc8h2f_block", "decode", "decode_block", "decode_message", "frame_crc", "messages_to_arrays",
    "package_version", "to_message",
]
