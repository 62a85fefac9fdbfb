"""The slcan hub relays whole Lawicel lines and counts every frame a client does not get (found
2026-12: at `sim-controller run --speedup 0` a slow reader lost frames the hub reported only as bytes,
cut mid-frame, and frames still queued when a client left or the hub stopped were not counted at all).

The tests feed the hub from a raw socket in batches and wait until the hub has taken each batch in, so
whether frames are dropped depends on the buffers only (kernel and ``max_buffer``), never on speed."""

from __future__ import annotations

import logging
import socket
import threading
from collections.abc import Iterator

import pytest

from protocol.slcan_hub import HubStats, SlcanHub, count_lines
from tests.waiting import wait_until

DEADLINE_S = 60.0                 # generous: the machine is shared; no speed is asserted
BATCH = 2000                      # frames per batch
MAX_BATCHES = 2000                # ~120 MB: far beyond any kernel socket buffer, so drops must come


def _frame(i: int) -> bytes:
    return b"t1238%016X\r" % i


class RunningHub(SlcanHub):
    """A hub serving on its own thread; ``shut_down()`` stops it as the command does (stop, join, close)."""

    def __init__(self) -> None:
        super().__init__(0, max_buffer=4096)
        self.thread = threading.Thread(target=self.serve_forever, daemon=True)
        self.thread.start()
        self.test_sockets: list[socket.socket] = []

    def shut_down(self) -> None:
        self.stop()
        self.thread.join(timeout=DEADLINE_S)
        assert not self.thread.is_alive()
        self.close()


@pytest.fixture
def hub() -> Iterator[RunningHub]:
    hub = RunningHub()
    try:
        yield hub
    finally:
        hub.shut_down()
        for sock in hub.test_sockets:
            sock.close()


def _connect(hub: RunningHub, receive_buffer: int | None = None) -> socket.socket:
    sock = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
    hub.test_sockets.append(sock)
    if receive_buffer is not None:          # before connecting: a small, fixed TCP window
        sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, receive_buffer)
    sock.connect(("127.0.0.1", hub.port))
    return sock


def _send_until_dropped(hub: RunningHub, sender: socket.socket) -> int:
    """Send batches of numbered frames until the hub dropped some, then one batch more; the number sent."""
    sent = batches_after_drop = 0
    for _ in range(MAX_BATCHES):
        sender.sendall(b"".join(_frame(i) for i in range(sent, sent + BATCH)))
        sent += BATCH
        assert wait_until(lambda: hub.stats.frames_in == sent, DEADLINE_S), hub.stats
        if hub.stats.dropped_frames:
            batches_after_drop += 1
            if batches_after_drop == 2:
                return sent
    pytest.fail(f"no frame dropped after {sent} frames: {hub.stats}")


def _read_lines(sock: socket.socket, until: int | None = None) -> list[bytes]:
    """Lines read from ``sock``: ``until`` of them, or all up to the end of the stream."""
    sock.settimeout(DEADLINE_S)
    data = bytearray()
    while until is None or count_lines(data) < until:
        chunk = sock.recv(65536)
        if not chunk:
            break
        data += chunk
    assert data.endswith(b"\r") or not data, "the hub cut a line"
    return [line + b"\r" for line in bytes(data).split(b"\r")[:-1]]


def _assert_in_order_and_whole(lines: list[bytes], sent: int) -> None:
    numbers = [int(line[5:-1], 16) for line in lines]
    assert all(line == _frame(n) for line, n in zip(lines, numbers))
    assert numbers == sorted(set(numbers)) and numbers[-1] < sent


def test_every_frame_a_slow_reader_misses_is_counted(hub, caplog):
    receiver = _connect(hub, receive_buffer=4096)
    sender = _connect(hub)
    assert wait_until(lambda: hub.connected == 2, DEADLINE_S)
    with caplog.at_level(logging.WARNING, logger="protocol.slcan_hub"):
        sent = _send_until_dropped(hub, sender)
        received = _read_lines(receiver, until=sent - hub.stats.dropped_frames)
        sender.close()
        hub.shut_down()
        received += _read_lines(receiver)          # nothing more: the hub closed the connection
    _assert_in_order_and_whole(received, sent)
    assert sent - len(received) == hub.stats.dropped_frames == hub.stats.lost_frames > 0
    assert hub.stats.dropped_bytes == hub.stats.dropped_frames * len(_frame(0))
    assert hub.stats.undelivered_frames == hub.stats.malformed_lines == 0
    messages = [r.getMessage() for r in caplog.records]
    assert any("does not read fast enough" in m for m in messages)
    assert f"lost {hub.stats.dropped_frames} frames" in messages[-1]


def test_frames_still_queued_when_the_hub_stops_are_counted(hub):
    receiver = _connect(hub, receive_buffer=4096)       # never reads until the hub stopped
    sender = _connect(hub)
    assert wait_until(lambda: hub.connected == 2, DEADLINE_S)
    sent = _send_until_dropped(hub, sender)
    sender.close()
    assert wait_until(lambda: hub.connected == 1, DEADLINE_S)
    hub.shut_down()
    received = _read_lines(receiver)       # what the kernel already held still arrives, then the end
    _assert_in_order_and_whole(received, sent)
    assert len(received) + hub.stats.dropped_frames + hub.stats.undelivered_frames == sent
    assert hub.stats.lost_frames == sent - len(received) > 0


@pytest.mark.parametrize("garbage", [143, 500])
def test_malformed_input_is_dropped_counted_and_never_cuts_a_line(hub, garbage):
    receiver = _connect(hub)
    sender = _connect(hub)
    assert wait_until(lambda: hub.connected == 2, DEADLINE_S)
    sender.sendall(b"x" * garbage)                  # longer than any slcan line, however the hub gets it
    sender.sendall(b"y\r" + _frame(1)[:7])          # the garbage's end, then half a frame
    sender.sendall(_frame(1)[7:] + _frame(2)[:4])    # the frame's rest, then a frame cut by the disconnect
    sender.close()
    assert wait_until(lambda: hub.connected == 1, DEADLINE_S)
    hub.shut_down()
    assert _read_lines(receiver) == [_frame(1)]
    assert hub.stats.frames_in == 1 and hub.stats.lost_frames == 0
    assert hub.stats.malformed_lines == 2 and hub.stats.malformed_bytes == garbage + 2 + 4


def test_the_longest_slcan_line_passes(hub):
    receiver = _connect(hub)
    sender = _connect(hub)
    assert wait_until(lambda: hub.connected == 2, DEADLINE_S)
    longest = b"D12345678F" + b"AB" * 64 + b"1234\r"    # CAN FD, extended ID, 64 bytes, timestamp
    assert len(longest) == 143
    sender.sendall(longest[:100])
    sender.sendall(longest[100:])
    sender.close()
    assert wait_until(lambda: hub.connected == 1, DEADLINE_S)
    hub.shut_down()
    assert _read_lines(receiver) == [longest]
    assert hub.stats.malformed_lines == 0


def test_the_summary_names_every_kind_of_loss():
    stats = HubStats(clients=3, frames_in=1000, dropped_frames=40, dropped_bytes=840, undelivered_frames=2,
                     malformed_lines=1, malformed_bytes=200)
    text = stats.summary()
    assert "received 1000 frames from 3 clients" in text
    assert "lost 42 frames" in text and "40 dropped (840 bytes)" in text and "2 still queued" in text
    assert "1 malformed input lines (200 bytes" in text
    assert HubStats(clients=1, frames_in=5).summary() == "received 5 frames from 1 clients"


def test_a_queue_smaller_than_a_line_is_refused():
    with pytest.raises(ValueError, match="max_buffer 100: must be ≥ 143"):
        SlcanHub(0, max_buffer=100)
