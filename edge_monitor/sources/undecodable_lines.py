"""Lines of a UTF-8 trace table that are not UTF-8 text (a few stray bytes a bad export or a bit flip left).

:func:`undecodable` finds them in a run of whole lines; :class:`MarkedLines` reads the file for pyarrow with
each such line replaced by :data:`MARKER`, a row of one cell (a separator is never a letter) that pyarrow's
``invalid_row_handler`` skips and counts like a row with the wrong number of cells, under its own line
number. Only used for a table that has such lines (:func:`trace_table.check_lines` counts them): a clean
table is read by pyarrow natively.
"""

from __future__ import annotations

import codecs
import io
from pathlib import Path
from typing import Callable, Iterator

#: What an undecodable line is replaced by (letters only: one cell whatever the separator).
MARKER = b"NotUtfEightText"


def undecodable(data: bytes, first_line: int) -> Iterator[tuple[int, int, int, str]]:
    """``(line number, start, end, what)`` of each line of ``data`` (whole lines, the first numbered
    ``first_line``) that is not UTF-8; ``start``/``end`` span the line without its line end, ``what`` names
    the byte and where it is in the line ("byte 0xff at byte 7", counted in bytes). The whole of ``data`` is decoded
    once; from its first bad line on, line by line (linear in ``data``, however many lines are bad)."""
    try:
        codecs.utf_8_decode(data, "strict", True)
        return
    except UnicodeDecodeError as exc:
        pos = data.rfind(b"\n", 0, exc.start) + 1
    line = first_line + data.count(b"\n", 0, pos)
    while pos < len(data):
        end = data.find(b"\n", pos)
        end = len(data) if end < 0 else end
        try:
            codecs.utf_8_decode(data[pos:end], "strict", True)
        except UnicodeDecodeError as exc:
            yield line, pos, end, f"byte 0x{data[pos + exc.start]:02x} at byte {exc.start + 1}"
        pos, line = end + 1, line + 1


def shown(line: bytes) -> str:
    """The first 80 bytes of an undecodable line as text (bad bytes as ``\\xff``)."""
    return line[:80].rstrip(b"\r").decode("utf-8", "backslashreplace")


class MarkedLines(io.RawIOBase):
    """The bytes of ``path`` with each line that is not UTF-8 replaced by :data:`MARKER`; ``seen(line
    number, description)`` is told of each."""

    def __init__(self, path: Path, block: int, seen: Callable[[int, str], None]) -> None:
        super().__init__()
        self._file = open(path, "rb")
        self._block, self._seen = block, seen
        self._out = bytearray()
        self._tail = b""
        self._line = 1            # number of the first line of the tail
        self._eof = False

    def readable(self) -> bool:
        return True

    def readinto(self, buffer: memoryview) -> int:    # type: ignore[override]
        while not self._out and not self._eof:
            self._fill()
        n = min(len(buffer), len(self._out))
        buffer[:n] = self._out[:n]
        del self._out[:n]
        return n

    def _fill(self) -> None:
        block = self._file.read(self._block)
        data = self._tail + block
        if block:
            cut = data.rfind(b"\n") + 1
        else:
            cut, self._eof = len(data), True
        whole, self._tail = data[:cut], data[cut:]
        pos = 0
        for number, start, end, what in undecodable(whole, self._line):
            self._seen(number, f"line {number}: not UTF-8 text ({what}): '{shown(whole[start:end])}'")
            self._out += whole[pos:start] + MARKER
            pos = end
        self._out += whole[pos:]
        self._line += whole.count(b"\n")

    def close(self) -> None:
        self._file.close()
        super().close()
