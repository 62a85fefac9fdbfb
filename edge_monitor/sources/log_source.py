"""Frame blocks from a python-can log file (.blf, .asc, .log, .trc, …), robust to damaged files.

python-can's readers stop at the first record they cannot parse. A replay should not, and it reads
the file as hostile (memory and time bounded by the file's size, whatever it holds):

* only a regular file is read (a FIFO would block, a device never ends): :class:`LogReadError`;
* a text log (.asc, .log, .trc, also gzip-compressed: .log.gz, …) is read line by line as bytes, each
  line decoded alone (:mod:`edge_monitor.sources.text_logs`): a line with an undecodable byte, a line
  python-can cannot parse or a line longer than :data:`MAX_LINE_BYTES` is skipped and counted, and
  reading goes on with the next line, so each costs at most its own frame; a compressed stream that
  ends early or is damaged ends the file there (truncation);
* a BLF file whose header size is smaller than a header or larger than the file cannot be read
  (:class:`LogReadError`); a BLF container that cannot be read (damaged zlib data, one inflating past
  its cap, a damaged object inside) is skipped, counted with an estimate of its frames, and the next
  one is read (:mod:`edge_monitor.sources.blf_blocks`); an object header or size the file cannot hold
  ends the walk there: truncation.

A log cut short (a BLF smaller than its header says or never finalised, or whose walk ended on
damage, an .asc without its closing ``End TriggerBlock``, a .log or .trc whose last line has no line
end, a compressed stream that ends early) is reported as truncated, so that its cut last cycle is not
published as complete. A file whose first :data:`MAX_CONSECUTIVE_SKIPS` records are all unreadable is
not a log (:class:`LogReadError`). What was skipped (records, and an upper bound of the frames in
them) and why the file ended are in :class:`LogReport`.
"""

from __future__ import annotations

import gzip
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
from can.io.trc import TRCReader

from edge_monitor.sources import blf_blocks
from edge_monitor.sources.frame_source import FrameArrays
from edge_monitor.sources.text_logs import MAX_LINE_BYTES, TextLines, is_text_log, text_format, trc_messages
from protocol.files import NotARegularFile, require_regular
from protocol.frames import messages_to_arrays

__all__ = ["LogReadError", "LogReport", "MAX_LINE_BYTES", "log_blocks", "log_blocks_with_position"]
log = logging.getLogger(__name__)

#: What python-can's readers raise on damaged content (BLFParseError is a plain Exception).
_DAMAGE = (ValueError, IndexError, KeyError, struct.error, zlib.error, EOFError, UnicodeDecodeError,
           can.io.blf.BLFParseError)
#: Text readers whose iteration can go on after a bad line (each line is one record; TRC: text_logs).
_LINE_READERS = (ASCReader, CanutilsLogReader)
#: This many unreadable records before the first frame: the file is not a log of this format.
MAX_CONSECUTIVE_SKIPS = 1000
#: Size of a BLF file header [bytes] (python-can reads it whole); a shorter file is cut before any frame.
BLF_FILE_HEADER_BYTES = 72


class LogReadError(ValueError):
    """The log file cannot be read at all (wrong format, unreadable header)."""


@dataclass
class LogReport:
    """What reading one log found: records skipped (with the first few reasons) and, if the file
    ends early, why (``truncated``)."""

    frames: int = 0
    skipped: int = 0
    frames_skipped: int = 0       # at most this many frames were in the skipped records (estimate for BLF)
    truncated: str | None = None
    examples: list[str] = field(default_factory=list)

    def skip(self, reason: str, frames: int = 1) -> None:
        """One record skipped that held at most ``frames`` frames; no frame read yet and too many
        skipped: :class:`LogReadError`."""
        self.skipped += 1
        self.frames_skipped += frames
        if len(self.examples) < 5:
            self.examples.append(reason)
        if self.frames == 0 and self.skipped >= MAX_CONSECUTIVE_SKIPS:
            raise LogReadError(f"not a readable log: its first {self.skipped} records are unreadable "
                               f"(first: {self.examples[0]})")

    def to_dict(self) -> dict[str, Any]:
        return {"frames": self.frames, "skipped_records": self.skipped, "frames_skipped": self.frames_skipped,
                "truncated": self.truncated, "skip_examples": list(self.examples)}


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
    try:
        require_regular(p)
    except NotARegularFile as exc:
        raise LogReadError(f"cannot read {p}: {exc.reason}; give a log file") from None
    if p.stat().st_size == 0:
        raise LogReadError(f"{p} is empty (0 bytes): was its recording stopped before it wrote anything?")
    if p.suffix.lower() == ".blf":
        _check_blf_header(p)
    report = report if report is not None else LogReport()
    reader = _open(p, report)
    with reader:
        if blf_blocks.supported(reader):
            yield from _blf_blocks(reader, block_size, report)
        else:
            yield from _message_blocks(reader, block_size, report)
        unpacked = _unpacked_bytes(reader)
    report.truncated = _cut_short(p, reader, unpacked) or report.truncated     # the file's own account first
    if report.skipped:
        log.warning("%s: %d unreadable record(s) skipped (first: %s)", p, report.skipped, report.examples[0])
    if report.truncated:
        log.warning("%s is truncated: %s", p, report.truncated)


def _open(p: Path, report: LogReport) -> Any:
    """python-can's reader for the file; a text log's reads its lines from :class:`TextLines`."""
    try:
        reader: Any = can.LogReader(str(p))
        if is_text_log(p):
            reader.file.close()
            reader.file = TextLines(p, report)     # duck-typed line source
    except (*_DAMAGE, OSError) as exc:
        raise LogReadError(f"cannot read {p} as a {p.suffix or 'CAN'} log: {exc or type(exc).__name__}") from exc
    return reader


def _check_blf_header(p: Path) -> None:
    """:class:`LogReadError` if a BLF file's header cannot be read: the file is shorter than a header,
    or its header size is smaller than one or larger than the file (python-can would read past it all)."""
    size = p.stat().st_size
    with open(p, "rb") as f:
        head = f.read(8)
    if not b"LOGG".startswith(head[:4]):
        return                                   # not a BLF file at all: python-can says so
    if size < BLF_FILE_HEADER_BYTES:
        raise LogReadError(f"{p} is truncated: {size} bytes, less than a BLF file header "
                           f"({BLF_FILE_HEADER_BYTES}): was its recording stopped before it wrote anything?")
    header_size = struct.unpack_from("<L", head, 4)[0]
    if not BLF_FILE_HEADER_BYTES <= header_size <= size:
        raise LogReadError(f"{p} has a damaged BLF header: header size {header_size} "
                           + (f"> file size {size}" if header_size > size else f"< {BLF_FILE_HEADER_BYTES}")
                           + " bytes; the file cannot be read: is it a copy of the log that was damaged?")


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
    container at a time (:mod:`edge_monitor.sources.blf_blocks`); damage ends the file as there."""
    parts: list[FrameArrays] = []
    held = 0
    try:
        for arrays in blf_blocks.container_arrays(reader, report.skip):
            report.frames += len(arrays[0])
            parts.append(arrays)
            held += len(arrays[0])
            while held >= block_size:
                joined = _join(parts)
                yield _slice(joined, 0, block_size), _bytes_read(reader)
                parts = [_slice(joined, block_size, held)] if held > block_size else []
                held -= block_size
    except LogReadError:
        raise
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
    it = trc_messages(reader, report) if isinstance(reader, TRCReader) else iter(reader)
    while True:
        try:
            msg = next(it)
        except StopIteration:
            return
        except LogReadError:
            raise
        except _DAMAGE as exc:
            where = f"after frame {report.frames}"
            if not isinstance(reader, _LINE_READERS):
                report.truncated = f"unreadable data {where}: {exc or type(exc).__name__}"
                return
            report.skip(f"line {where}: {exc}")
            it = _resume(reader)
            continue
        report.frames += 1
        yield msg


def _resume(reader: Any) -> Iterator[can.Message]:
    """Go on reading a text log after a bad line: the file iterator is past it; the header (ASC) is
    already known, so it must not be searched for again."""
    if isinstance(reader, ASCReader):
        reader._extract_header = lambda: None  # type: ignore[method-assign]  # keep base, start time, …
    return iter(reader)


def _unpacked_bytes(reader: Any) -> int | None:
    """Bytes a gzip-compressed log unpacked to, read to its end; None for a file read as it is on disk."""
    file = getattr(reader, "file", None)
    return file.tell() if isinstance(file, gzip.GzipFile) and not file.closed else None


def _cut_short(path: Path, reader: Any, unpacked: int | None = None) -> str | None:
    """Why the file looks cut short, or None. Only formats with a way to tell (a compressed BLF by the
    bytes it ``unpacked`` to)."""
    lines = getattr(reader, "file", None)
    if isinstance(lines, TextLines):
        return lines.cut_short(asc=text_format(path) == ".asc")
    if not isinstance(reader, BLFReader):
        return None
    try:
        size = path.stat().st_size if unpacked is None else unpacked
    except OSError as exc:
        return f"cannot check the end of the file: {exc}"
    if not reader.file_size:
        return "BLF header never finalised (the writer did not close the file)"
    if size < reader.file_size:
        return f"BLF file has {size} bytes, its header says {reader.file_size}"
    return None


def _bytes_read(reader: object) -> int:
    """Position of the reader's underlying file descriptor (compressed bytes for .gz logs)."""
    try:
        return os.lseek(reader.file.fileno(), 0, os.SEEK_CUR)   # type: ignore[attr-defined]
    except (AttributeError, OSError, ValueError):
        return 0
