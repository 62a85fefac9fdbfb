"""The chunked slcan reader: same frames as python-can's slcan, malformed lines counted, not raised,
linear-time line splitting with a bounded line length."""

from __future__ import annotations

import collections
import os
import queue
import re
import time

import can
import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from protocol import frames as fr
from protocol.links import PtyPair, open_bus
from protocol.slcan_fast import MAX_LINE_LENGTH, FastSlcanBus, SlcanLineSplitter

FUZZ_EXAMPLES = int(os.environ.get("FUZZ_EXAMPLES", "300"))  # e.g. FUZZ_EXAMPLES=20000 for a long local run
DEADLINE_S = 60.0  # generous: the machine is shared; no speed is asserted


def test_frames_over_a_pty_arrive_intact_and_in_order():
    sent = [fr.to_message(fr.MOTOR_STATE_BASE_ID + 2, fr.encode_motor_state(2, i % 256, 0.01 * i, i, 0.0))
            for i in range(500)]
    with PtyPair() as pair, open_bus(f"slcan:{pair.a}") as tx, open_bus(f"slcan:{pair.b}") as rx:
        assert isinstance(rx, FastSlcanBus)
        for m in sent:
            tx.send(m)
        got = []
        while len(got) < len(sent):
            m = rx.recv(timeout=10)
            assert m is not None, f"only {len(got)} of {len(sent)} frames arrived"
            got.append(m)
    assert [(m.arbitration_id, bytes(m.data), m.is_extended_id) for m in got] == \
        [(m.arbitration_id, bytes(m.data), False) for m in sent]


def _write_raw(path: str, data: bytes) -> None:
    fd = os.open(path, os.O_WRONLY | os.O_NOCTTY)
    try:
        view = memoryview(data)
        while view:
            view = view[os.write(fd, view):]
    finally:
        os.close(fd)


def _receive(rx: FastSlcanBus, count: int, done=lambda: True) -> list[can.Message]:
    frames: list[can.Message] = []
    deadline = time.monotonic() + DEADLINE_S
    while (len(frames) < count or not done()) and time.monotonic() < deadline:
        m = rx.recv(timeout=0.2)
        if m is not None:
            frames.append(m)
    return frames


def test_garbage_on_the_line_is_counted_and_reading_continues():
    with PtyPair() as pair, open_bus(f"slcan:{pair.b}") as rx:
        _write_raw(pair.a, b"t1008ZZZZZZZZZZZZZZZZ\rt10080102030405060708\r\xff\xfe\r")
        frames = _receive(rx, 1, lambda: rx.malformed_lines >= 2)
        assert [bytes(m.data) for m in frames] == [bytes(range(1, 9))]
        assert rx.malformed_lines == 2 and rx.overlong_lines == 0
        assert isinstance(rx, can.BusABC)


def _slcan_line(arbitration_id: int, data: bytes) -> bytes:
    return f"t{arbitration_id:03X}{len(data)}{data.hex().upper()}\r".encode()


def test_200_kb_without_terminator_is_dropped_and_counted_then_frames_arrive():
    """A baud-rate mismatch: 200 KB without a line terminator, then valid frames. The garbage runs
    into the first frame's line, so that line is lost with it (one overlong line); the rest arrive."""
    rng = np.random.default_rng(7)
    garbage = rng.integers(0, 256, 200_000, dtype=np.uint8)
    garbage = garbage[(garbage != 0x0D) & (garbage != 0x07)].tobytes()
    payloads = [fr.encode_motor_state(1, i, 0.001 * i, 0.5 * i, 0.0) for i in range(20)]
    lines = [_slcan_line(fr.MOTOR_STATE_BASE_ID + 1, p) for p in payloads]
    with PtyPair() as pair, open_bus(f"slcan:{pair.b}") as rx:
        _write_raw(pair.a, garbage + b"".join(lines))
        frames = _receive(rx, len(payloads) - 1)
        assert [bytes(m.data) for m in frames] == payloads[1:]
        assert rx.overlong_lines == 1 and rx.malformed_lines == 1
        assert rx.discarded_bytes == len(garbage) + len(lines[0])
        assert pair.dropped_bytes == 0


def _reference_split(stream: bytes, max_line: int) -> tuple[list[str], int, int, int]:
    """Model: lines end after each terminator; overlong (also an unfinished tail) or non-ASCII
    lines are malformed. -> (lines, malformed, overlong, discarded bytes)."""
    *complete, tail = re.split(rb"(?<=[\r\a])", stream)
    lines, malformed, overlong, discarded = [], 0, 0, 0
    for line in complete:
        if len(line) > max_line:
            overlong, malformed, discarded = overlong + 1, malformed + 1, discarded + len(line)
        else:
            try:
                lines.append(line.decode("ascii"))
            except UnicodeDecodeError:
                malformed += 1
    if len(tail) > max_line:
        overlong, malformed, discarded = overlong + 1, malformed + 1, discarded + len(tail)
    return lines, malformed, overlong, discarded


_pieces = st.one_of(
    st.sampled_from([b"t1008" + b"00" * 8 + b"\r", b"T123456788" + b"AB" * 8 + b"\r", b"\r", b"\a", b"z\r"]),
    st.binary(max_size=40),
    st.binary(min_size=100, max_size=400).map(lambda b: b.replace(b"\r", b"x").replace(b"\a", b"y")),
)


@settings(max_examples=FUZZ_EXAMPLES, deadline=None)
@given(st.lists(_pieces, max_size=30), st.lists(st.integers(1, 300), min_size=1, max_size=20),
       st.integers(1, 160))
def test_line_splitter_equals_the_model_for_any_chunking(pieces, cuts, max_line):
    stream = b"".join(pieces)
    splitter = SlcanLineSplitter(max_line)
    lines, position, k = [], 0, 0
    while position < len(stream):
        size = cuts[k % len(cuts)]
        lines += splitter.feed(stream[position:position + size])
        position, k = position + size, k + 1
    expected, malformed, overlong, discarded = _reference_split(stream, max_line)
    assert lines == expected
    assert (splitter.malformed_lines, splitter.overlong_lines, splitter.discarded_bytes) == \
        (malformed, overlong, discarded)
    assert len(splitter._partial) <= max_line  # never unbounded buffering


def test_line_splitter_is_linear_on_unterminated_input():
    splitter = SlcanLineSplitter()
    for _ in range(200):                       # 200 × 4 KB without a terminator
        assert splitter.feed(b"\x55" * 4096) == []
        assert len(splitter._partial) <= MAX_LINE_LENGTH
    assert splitter.feed(b"\rt1000\r") == ["t1000\r"]
    assert (splitter.overlong_lines, splitter.discarded_bytes) == (1, 200 * 4096 + 1)


class _ParserOnly(FastSlcanBus):
    """python-can's slcan parser behind FastSlcanBus, fed from a list of lines (no serial port)."""

    def __init__(self, lines: list[str]) -> None:  # noqa: D107 - deliberately no super().__init__
        self._lines = collections.deque(lines)
        self._splitter = SlcanLineSplitter()
        self._parse_errors = 0
        self._queue = queue.SimpleQueue()
        self._is_shutdown = True

    def _read(self, timeout):
        return self._lines.popleft() if self._lines else None


_lawicel_like = st.builds(
    lambda head, body: head + body,
    st.sampled_from(list("tTrRdDbBxFVNzZ\a\r ")),
    st.text(alphabet="0123456789ABCDEFabcdef-+_ xZ", max_size=MAX_LINE_LENGTH - 2),
)


@settings(max_examples=FUZZ_EXAMPLES, deadline=None)
@given(st.one_of(_lawicel_like.map(str.encode), st.binary(max_size=MAX_LINE_LENGTH - 1)))
def test_python_can_parser_never_raises_into_the_reader(line):
    """Whatever line the splitter hands on, the bus's receive path returns a message or None."""
    bus = _ParserOnly(SlcanLineSplitter().feed(line + b"\r"))
    for _ in range(2):
        message, _ = bus._recv_internal(0)
        assert message is None or isinstance(message, can.Message)


def test_flush_forgets_partial_and_queued_lines():
    with PtyPair() as pair, open_bus(f"slcan:{pair.b}") as rx:
        _write_raw(pair.a, b"t1008" + b"11" * 8 + b"\rt1008" + b"22")   # one line and half a line
        frames = _receive(rx, 0, lambda: rx._splitter._partial)
        assert [bytes(m.data) for m in frames] == [b"\x11" * 8]
        rx.flush()
        _write_raw(pair.a, b"33" * 7 + b"\rt1008" + b"44" * 8 + b"\r")  # rest of the half line, one line
        frames = _receive(rx, 1)        # the orphaned tail "3333…\r" is no command: python-can skips it
        assert [bytes(m.data) for m in frames] == [b"\x44" * 8]
