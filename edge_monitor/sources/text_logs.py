"""The lines of a text CAN log (.asc, .log, .trc, and these gzip-compressed), read as hostile.

python-can's text readers take a file of ``str`` lines and stop at the first one they cannot decode or
parse. :class:`TextLines` is the line source they are given instead: the file is read as bytes, at most
:data:`MAX_LINE_BYTES` at a time (a longer line, a sparse file or a gzip bomb of one endless line is
skipped in pieces: memory bounded), each line decoded alone (an undecodable byte costs its own line), and
the end of a compressed stream that is cut short or damaged ends the file as truncation instead of being
raised again at every read. It also tells how the file ended (:meth:`TextLines.cut_short`).

:func:`trc_messages` reads a PCAN trace (.trc) as python-can's ``TRCReader`` does, except that a line
it cannot parse is skipped and counted, and reading goes on with the next one.
"""

from __future__ import annotations

import gzip
import io
import logging
import struct
import zlib
from pathlib import Path
from typing import Iterator, Protocol

import can
from can.io.trc import TRCFileVersion, TRCReader

log = logging.getLogger(__name__)

#: Longest line of a text log read [bytes]; a longer one is skipped in pieces (a frame line is < 200).
MAX_LINE_BYTES = 4096
#: Damage a compressed stream raises on reading: it ends the file (raised again at every further read).
_STREAM_DAMAGE = (EOFError, zlib.error, gzip.BadGzipFile)
#: Record types of a PCAN trace that are no frame (status, error counter, error frame, event; warnings,
#: errors and version 1.0's bus line): python-can passes them over, and so are they here, uncounted.
TRC_OTHER_RECORDS = frozenset({"ST", "EC", "ER", "EV", "Warng", "Error", "Event", "FFFFFFFF"})


class Report(Protocol):
    """What reading counts (:class:`edge_monitor.sources.log_source.LogReport`)."""

    frames: int

    def skip(self, reason: str, frames: int = 1) -> None: ...


def is_text_log(path: Path) -> bool:
    """The file is a text log this module reads (.asc, .log, .trc, optionally gzip-compressed)."""
    suffixes = [s.lower() for s in path.suffixes[-2:]]
    if suffixes and suffixes[-1] == ".gz":
        suffixes = suffixes[:-1]
    return bool(suffixes) and suffixes[-1] in (".asc", ".log", ".trc")


def text_format(path: Path) -> str:
    """The text log's format suffix (".asc", ".log", ".trc"), a ``.gz`` after it left off."""
    suffixes = [s.lower() for s in path.suffixes[-2:]]
    return suffixes[-2] if suffixes[-1] == ".gz" and len(suffixes) == 2 else suffixes[-1]


class TextLines:
    """The lines of a text log for python-can's reader (its ``file``), as the module docstring says:
    skipped lines are counted in ``report``; :attr:`stream_end` says why a compressed stream ended early."""

    def __init__(self, path: Path, report: Report) -> None:
        gz = path.suffix.lower() == ".gz"
        self._raw: gzip.GzipFile | io.BufferedReader = gzip.open(path, "rb") if gz else open(path, "rb")
        self.report = report
        self.stream_end: str | None = None
        self._last = b""          # the last line read (or piece of a long one)
        self._last_text = b""     # the last line that is not blank

    def __iter__(self) -> TextLines:
        return self

    def __next__(self) -> str:
        while True:
            line = self._read()
            if not line:
                raise StopIteration
            if len(line) > MAX_LINE_BYTES:
                while line and not line.endswith(b"\n"):
                    line = self._read(MAX_LINE_BYTES)
                self.report.skip(f"line after frame {self.report.frames}: longer than {MAX_LINE_BYTES} bytes")
                continue
            try:
                return line.decode("utf-8")
            except UnicodeDecodeError as exc:
                self.report.skip(f"line after frame {self.report.frames}: undecodable byte ({exc.reason})")

    def _read(self, size: int = MAX_LINE_BYTES + 1) -> bytes:
        """The next line (at most ``size`` bytes of it); b"" at the end, also of a damaged compressed stream."""
        if self.stream_end is not None:
            return b""
        try:
            line = self._raw.readline(size)
        except _STREAM_DAMAGE as exc:
            self.stream_end = (f"compressed stream ends early after frame {self.report.frames}"
                               if isinstance(exc, EOFError) else
                               f"compressed stream damaged after frame {self.report.frames} ({exc})")
            return b""
        if line:
            self._last = line
            if not line.isspace():
                self._last_text = line
        return line

    def cut_short(self, asc: bool) -> str | None:
        """Why the file looks cut short, or None: the compressed stream ended early, an ASC file has
        no closing ``End TriggerBlock``, the last line has no line end. Known once read to the end."""
        if self.stream_end:
            return self.stream_end
        if asc and b"End TriggerBlock" not in self._last_text:
            return "no 'End TriggerBlock' at the end of the ASC file"
        if self._last and not self._last.endswith(b"\n"):
            return "the last line has no line end"
        return None

    def fileno(self) -> int:
        return self._raw.fileno()

    def close(self) -> None:
        self._raw.close()


def trc_messages(reader: TRCReader, report: Report) -> Iterator[can.Message]:
    """The frames of a PCAN trace read from ``reader.file`` (a :class:`TextLines`); a line python-can
    cannot parse, or of a record type PCAN does not write, is skipped and counted."""
    first = reader._extract_header()        # the header's version and columns; the first line after it
    lines = iter(reader.file)
    line: str | None = first
    while line is not None:
        text = line.strip()
        if text and not text.startswith(";"):
            msg = _trc_line(reader, text, report)
            if msg is not None:
                yield msg
        line = next(lines, None)
    reader.stop()


def _trc_line(reader: TRCReader, text: str, report: Report) -> can.Message | None:
    """One trace line's frame; None for a record that is no frame or a line skipped (counted)."""
    try:
        cols = tuple(text.split(maxsplit=reader._num_columns))
        msg = reader._parse_cols(cols)
        if msg is None and _record_type(reader, cols) not in TRC_OTHER_RECORDS:
            raise ValueError(f"unknown record type {_record_type(reader, cols)[:20]!r}")
    except (ValueError, IndexError, KeyError, struct.error) as exc:
        report.skip(f"line after frame {report.frames}: {exc or type(exc).__name__}")
        return None
    return msg


def _record_type(reader: TRCReader, cols: tuple[str, ...]) -> str:
    """A trace line's record type (Rx/Tx in version 1.x, DT, FD, … in 2.x; the id in 1.0)."""
    if reader.file_version >= TRCFileVersion.V2_0:
        return cols[reader.columns["T"]]
    return cols[3] if reader.file_version == TRCFileVersion.V1_3 else cols[2]
