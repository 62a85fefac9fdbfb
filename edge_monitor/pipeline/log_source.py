"""Frame blocks from a python-can log file (.blf, .asc, .log, …), robust to damaged files.

python-can's readers stop at the first record they cannot parse. A replay should not: a bad line in
a text log (.asc, .log) is skipped and counted and reading goes on with the next line; an unreadable
record in a binary log (.blf) ends the file there. A log cut short (a BLF smaller than its header
says or never finalised, an .asc without its closing ``End TriggerBlock``, a .log whose last line has
no line end) is reported as truncated, so that its cut last cycle is not published as complete.
What was skipped and why the file ended are in :class:`LogReport`.
"""

from __future__ import annotations

import logging
import os
import struct
import zlib
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Iterator

import can
import numpy as np
from can.io.asc import ASCReader
from can.io.blf import BLFReader
from can.io.canutils import CanutilsLogReader

from edge_monitor.pipeline import blf_blocks
from edge_monitor.pipeline.frame_source import FrameArrays
from protocol.frames import messages_to_arrays

log = logging.getLogger(__name__)

#: What python-can's readers raise on damaged content (BLFParseError is a plain Exception).
_DAMAGE = (ValueError, IndexError, KeyError, struct.error, zlib.error, EOFError, UnicodeDecodeError,
           can.io.blf.BLFParseError)
#: Text readers whose iteration can go on after a bad line (each line is one record).
_LINE_READERS = (ASCReader, CanutilsLogReader)
#: More skipped records than this in a row: the file is not a log of this format.
MAX_CONSECUTIVE_SKIPS = 1000


class LogReadError(ValueError):
    """The log file cannot be read at all (wrong format, unreadable header)."""


@dataclass
class LogReport:
    """What reading one log found: records skipped (with the first few reasons) and, if the file
    ends early, why (``truncated``)."""

    frames: int = 0
    skipped: int = 0
    truncated: str | None = None
    examples: list[str] = field(default_factory=list)

    def skip(self, reason: str) -> None:
        self.skipped += 1
        if len(self.examples) < 5:
            self.examples.append(reason)

    def to_dict(self) -> dict[str, Any]:
        return {"frames": self.frames, "skipped_records": self.skipped, "truncated": self.truncated,
                "skip_examples": list(self.examples)}


def log_blocks(path: str | Path, block_size: int = 4096) -> Iterator[FrameArrays]:
    """Yield the frames of a python-can log file as array blocks, in file order."""
    for block, _ in log_blocks_with_position(path, block_size):
        yield block


def log_blocks_with_position(path: str | Path, block_size: int = 4096,
                             report: LogReport | None = None) -> Iterator[tuple[FrameArrays, int]]:
    """As :func:`log_blocks`, each block with the bytes of the file read so far (for a progress bar;
    read-ahead makes it run early, 0 where the reader does not tell). Damage is skipped or ends the
    file as the module docstring says, recorded in ``report``; :class:`LogReadError` if the file
    cannot be opened as a log at all."""
    p = Path(path)
    if not p.exists():
        raise FileNotFoundError(f"log file {p} not found")
    report = report if report is not None else LogReport()
    try:
        reader = can.LogReader(str(p))
    except (*_DAMAGE, OSError) as exc:
        raise LogReadError(f"cannot read {p} as a {p.suffix or 'CAN'} log: {exc or type(exc).__name__}") from exc
    with reader:
        if blf_blocks.supported(reader):
            yield from _blf_blocks(reader, block_size, report)
        else:
            yield from _message_blocks(reader, block_size, report)
    report.truncated = report.truncated or _cut_short(p, reader)
    if report.skipped:
        log.warning("%s: %d unreadable record(s) skipped (first: %s)", p, report.skipped, report.examples[0])
    if report.truncated:
        log.warning("%s is truncated: %s", p, report.truncated)


def _message_blocks(reader: Any, block_size: int, report: LogReport) -> Iterator[tuple[FrameArrays, int]]:
    """Any log python-can reads, one message at a time, in blocks of ``block_size``."""
    buf: list[can.Message] = []
    for msg in _messages(reader, report):
        buf.append(msg)
        if len(buf) >= block_size:
            yield messages_to_arrays(buf), _bytes_read(reader)
            buf = []
    if buf:
        yield messages_to_arrays(buf), _bytes_read(reader)


def _blf_blocks(reader: Any, block_size: int, report: LogReport) -> Iterator[tuple[FrameArrays, int]]:
    """A .blf file's frames in blocks of ``block_size`` (as the per-message path cuts them), read a
    container at a time (:mod:`edge_monitor.pipeline.blf_blocks`); damage ends the file as there."""
    parts: list[FrameArrays] = []
    held = 0
    try:
        for arrays in blf_blocks.container_arrays(reader):
            report.frames += len(arrays[0])
            parts.append(arrays)
            held += len(arrays[0])
            while held >= block_size:
                joined = _join(parts)
                yield _slice(joined, 0, block_size), _bytes_read(reader)
                parts = [_slice(joined, block_size, held)] if held > block_size else []
                held -= block_size
    except _DAMAGE as exc:
        report.truncated = f"unreadable data after frame {report.frames}: {exc or type(exc).__name__}"
    if held:
        yield _join(parts), _bytes_read(reader)


def _join(parts: list[FrameArrays]) -> FrameArrays:
    if len(parts) == 1:
        return parts[0]
    ids, data, dlc, ts = zip(*parts)
    return np.concatenate(ids), np.concatenate(data), np.concatenate(dlc), np.concatenate(ts)


def _slice(arrays: FrameArrays, start: int, stop: int) -> FrameArrays:
    ids, data, dlc, ts = arrays
    return ids[start:stop], data[start:stop], dlc[start:stop], ts[start:stop]


def _messages(reader: Any, report: LogReport) -> Iterator[can.Message]:
    """The reader's messages; a bad line of a text log is skipped, other damage ends the file."""
    it = iter(reader)
    in_a_row = 0
    while True:
        try:
            msg = next(it)
        except StopIteration:
            return
        except _DAMAGE as exc:
            where = f"after frame {report.frames}"
            if not isinstance(reader, _LINE_READERS) or in_a_row >= MAX_CONSECUTIVE_SKIPS:
                report.truncated = f"unreadable data {where}: {exc or type(exc).__name__}"
                return
            report.skip(f"line {where}: {exc}")
            in_a_row += 1
            it = _resume(reader)
            continue
        in_a_row = 0
        report.frames += 1
        yield msg


def _resume(reader: Any) -> Iterator[can.Message]:
    """Go on reading a text log after a bad line: the file iterator is past it; the header (ASC) is
    already known, so it must not be searched for again."""
    if isinstance(reader, ASCReader):
        reader._extract_header = lambda: None  # type: ignore[method-assign]  # keep base, start time, …
    return iter(reader)


def _cut_short(path: Path, reader: Any) -> str | None:
    """Why the file looks cut short, or None. Only formats with a way to tell."""
    try:
        if isinstance(reader, BLFReader):
            size = path.stat().st_size
            if not reader.file_size:
                return "BLF header never finalised (the writer did not close the file)"
            if size < reader.file_size:
                return f"BLF file has {size} bytes, its header says {reader.file_size}"
            return None
        if path.suffix.lower() not in (".asc", ".log"):
            return None
        with open(path, "rb") as f:
            f.seek(max(0, path.stat().st_size - 512))
            tail = f.read()
    except OSError as exc:
        return f"cannot check the end of the file: {exc}"
    if path.suffix.lower() == ".asc" and b"End TriggerBlock" not in tail:
        return "no 'End TriggerBlock' at the end of the ASC file"
    if tail and not tail.endswith(b"\n"):
        return "the last line has no line end"
    return None


def _bytes_read(reader: object) -> int:
    """Position of the reader's underlying file descriptor (compressed bytes for .gz logs)."""
    try:
        return os.lseek(reader.file.fileno(), 0, os.SEEK_CUR)   # type: ignore[attr-defined]
    except (AttributeError, OSError, ValueError):
        return 0
