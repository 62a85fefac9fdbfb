"""A python-can slcan bus that reads the serial line in chunks instead of byte by byte.

python-can's ``slcanBus._read`` (4.6.1, the latest release on PyPI when this was written) makes
one ``read(1)`` system call per byte (~30 per frame). In a process where another thread does
numeric work, each of those calls must re-acquire the GIL, so receiving collapses to a few hundred
frames/s (measured here: ~450 frames/s next to the agent's processing thread, against ~7,000
frames/s sent). The same fix is merged upstream (python-can PR #2028, issue #2027) but not in a
release yet; drop this override once a python-can release contains it.

This subclass reads whatever the line holds in one call and splits it into Lawicel lines in
linear time (one scan for the terminators ``\\r``/``\\a`` per chunk), handing them to python-can's
own parser one by one. Input without terminators (e.g. a baud-rate mismatch) cannot grow a buffer:
a line longer than ``MAX_LINE_LENGTH`` is dropped up to the next terminator — the valid frame the
garbage runs into goes with it — and counted in ``overlong_lines`` (and ``discarded_bytes``).
Malformed lines (bad hex, not ASCII, overlong) are counted in ``malformed_lines``, never raised
into the Notifier thread.
"""

from __future__ import annotations

import collections
import logging
import re
import time
from typing import Any, Optional

import can
from can.interfaces.slcan import slcanBus

log = logging.getLogger(__name__)

#: Longest legal Lawicel line in bytes: CAN FD extended frame ``D`` + 8 ID digits + DLC digit
#: + 64 data bytes as 128 hex digits + 4 timestamp digits + terminator = 143. Anything longer is
#: garbage (classical frames are at most 31 bytes).
MAX_LINE_LENGTH = 143
_TERMINATOR = re.compile(rb"[\r\a]")
_MAX_CHUNK = 1 << 16


class SlcanLineSplitter:
    """Splits a byte stream into Lawicel lines (terminator included) in linear time.

    ``feed(chunk)`` returns the complete lines of the chunk as ASCII strings. Bytes after the last
    terminator wait for the next chunk, at most ``max_line`` of them; a longer line is discarded
    up to and including its terminator and counted once in ``overlong_lines``. Counters:
    ``malformed_lines`` (overlong or not ASCII), ``overlong_lines``, ``discarded_bytes``.
    """

    def __init__(self, max_line: int = MAX_LINE_LENGTH) -> None:
        self.max_line = max_line
        self.malformed_lines = 0
        self.overlong_lines = 0
        self.discarded_bytes = 0
        self._partial = bytearray()
        self._discarding = False   # inside an overlong line: drop up to the next terminator

    def reset(self) -> None:
        """Forget a partial line (after the input was flushed); counters are kept."""
        self._partial.clear()
        self._discarding = False

    def feed(self, chunk: bytes | bytearray) -> list[str]:
        """Complete lines ending in this chunk, oldest first."""
        lines: list[str] = []
        start = 0
        for match in _TERMINATOR.finditer(chunk):
            end = match.end()
            if self._discarding:
                self._discarding = False
                self.discarded_bytes += end - start
            elif len(self._partial) + end - start > self.max_line:
                self._count_overlong(len(self._partial) + end - start)
            else:
                line = bytes(self._partial + chunk[start:end]) if self._partial else bytes(chunk[start:end])
                try:
                    lines.append(line.decode("ascii"))
                except UnicodeDecodeError:
                    self.malformed_lines += 1
            self._partial.clear()
            start = end
        self._keep_tail(chunk, start)
        return lines

    def _keep_tail(self, chunk: bytes | bytearray, start: int) -> None:
        tail = len(chunk) - start
        if self._discarding:
            self.discarded_bytes += tail
        elif len(self._partial) + tail > self.max_line:
            self._count_overlong(len(self._partial) + tail)
            self._partial.clear()
            self._discarding = True
        else:
            self._partial += chunk[start:]

    def _count_overlong(self, size: int) -> None:
        self.overlong_lines += 1
        self.malformed_lines += 1
        self.discarded_bytes += size
        if self.overlong_lines == 1 or self.overlong_lines % 1000 == 0:
            log.warning("slcan: dropped %d overlong line(s) without terminator (baud-rate mismatch or "
                        "not an slcan device?)", self.overlong_lines)


class FastSlcanBus(slcanBus):
    """slcan over a serial device, pseudo-terminal or ``socket://`` URL with chunked reads.

    ``malformed_lines`` counts lines python-can could not parse plus overlong lines;
    ``overlong_lines`` and ``discarded_bytes`` break the garbage down.
    """

    def __init__(self, channel: str, *args: Any, **kwargs: Any) -> None:
        self._lines: collections.deque[str] = collections.deque()
        self._splitter = SlcanLineSplitter()
        self._parse_errors = 0
        super().__init__(channel, *args, **kwargs)

    @property
    def malformed_lines(self) -> int:
        return self._parse_errors + self._splitter.malformed_lines

    @property
    def overlong_lines(self) -> int:
        return self._splitter.overlong_lines

    @property
    def discarded_bytes(self) -> int:
        return self._splitter.discarded_bytes

    def flush(self) -> None:
        """Drop buffered lines and input, as python-can's ``flush`` does for its own buffer."""
        self._lines.clear()
        self._splitter.reset()
        super().flush()

    def _read(self, timeout: Optional[float]) -> Optional[str]:
        if self._lines:
            return self._lines.popleft()
        port = self.serialPortOrig
        end = None if timeout is None else time.monotonic() + max(timeout, 0.0)
        while True:
            waiting = port.in_waiting
            chunk = port.read(min(max(waiting, 1), _MAX_CHUNK))
            if chunk:
                self._lines.extend(self._splitter.feed(chunk))
                if self._lines:
                    return self._lines.popleft()
            if end is not None and time.monotonic() >= end:
                return None

    def _recv_internal(self, timeout: Optional[float]) -> tuple[Optional[can.Message], bool]:
        try:
            return super()._recv_internal(timeout)
        except (ValueError, IndexError):
            self._parse_errors += 1
            return None, False
