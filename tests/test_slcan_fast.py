"""The chunked slcan reader: same frames as python-can's slcan, malformed lines counted, not raised."""

from __future__ import annotations

import can

from protocol import frames as fr
from protocol.links import PtyPair, open_bus
from protocol.slcan_fast import FastSlcanBus


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


def test_garbage_on_the_line_is_counted_and_reading_continues():
    with PtyPair() as pair, open_bus(f"slcan:{pair.b}") as rx:
        import os
        fd = os.open(pair.a, os.O_WRONLY | os.O_NOCTTY)
        try:
            os.write(fd, b"t1008ZZZZZZZZZZZZZZZZ\rt10080102030405060708\r\xff\xfe\r")
        finally:
            os.close(fd)
        frames = []
        for _ in range(50):
            m = rx.recv(timeout=0.2)
            if m is not None:
                frames.append(m)
            if rx.malformed_lines >= 2 and frames:
                break
        assert [bytes(m.data) for m in frames] == [bytes(range(1, 9))]
        assert rx.malformed_lines == 2
        assert isinstance(rx, can.BusABC)
