"""Links: virtual bus, slcan over a bridged pty between two processes, socketcan:vcan0 (where the
kernel has it), log-file round trips, and link errors."""

import subprocess
import sys
import textwrap
import time
import uuid
from pathlib import Path

import can
import numpy as np
import pytest

from protocol import frames as F
from protocol.e2e import E2EReceiver, E2EStatus
from protocol.links import LinkError, PtyPair, is_log_file, open_bus, open_log_reader, open_log_writer, vcan_available

N_TICKS = 300  # controller ticks sent by the peer process
JOINTS = 2
STATUS_EVERY = 10
EXPECTED_FRAMES = N_TICKS * JOINTS + N_TICKS // STATUS_EVERY
DEADLINE_S = 60.0  # generous: the machine is shared; no speed is asserted

SENDER = textwrap.dedent(
    """
    import sys, time
    import numpy as np
    from protocol import frames as F
    from protocol.links import open_bus

    link, n_ticks, joints, every = sys.argv[1], int(sys.argv[2]), int(sys.argv[3]), int(sys.argv[4])
    ticks = np.arange(n_ticks)
    rows = [F.encode_motor_state_block(j, ticks, 0.5 * np.sin(ticks / 50.0), 0.01 * ticks, 0.003 * ticks)
            for j in range(joints)]
    bus = open_bus(link)
    for tick in range(n_ticks):
        for j in range(joints):
            bus.send(F.to_message(F.MOTOR_STATE_BASE_ID + j, rows[j][tick].tobytes()))
        if tick % every == 0:
            bus.send(F.to_message(F.CONTROLLER_STATUS_ID,
                                  F.encode_controller_status(tick // every, F.Mode.TEST_CYCLE, 1, 2, tick)))
        if tick % 50 == 0:
            time.sleep(0.01)  # a real controller paces its ticks; also keeps the pty buffers small
    time.sleep(1.0)  # let the link drain before closing
    bus.shutdown()
    print("sent", n_ticks)
    """
)


def _receive_and_check(bus: can.BusABC, sender: subprocess.Popen) -> None:
    received: list[can.Message] = []
    deadline = time.monotonic() + DEADLINE_S
    while len(received) < EXPECTED_FRAMES and time.monotonic() < deadline:
        msg = bus.recv(timeout=0.5)
        if msg is not None:
            received.append(msg)
    out, err = sender.communicate(timeout=DEADLINE_S)
    assert sender.returncode == 0, err
    assert len(received) == EXPECTED_FRAMES, f"got {len(received)} of {EXPECTED_FRAMES} frames; sender: {out} {err}"
    assert all(not m.is_extended_id for m in received)

    ids, data, dlc, timestamps = F.messages_to_arrays(received)
    block = F.decode_block(ids, data, dlc)
    assert block.valid.all(), block.error_counts()
    statuses, lost = E2EReceiver(timeout_s=5.0).check_block(ids, block.counter, block.crc_ok, timestamps)
    assert (statuses == E2EStatus.OK).all() and lost.sum() == 0
    ticks = np.arange(N_TICKS)
    for j in range(JOINTS):
        rows = block.kind == F.FrameKind.MOTOR_STATE
        rows &= block.joint == j
        assert block.counter[rows].tolist() == (ticks % 256).tolist()
        np.testing.assert_allclose(block.torque[rows], 0.5 * np.sin(ticks / 50.0), atol=F.TORQUE_SCALE / 2 + 1e-12)
        np.testing.assert_allclose(block.speed[rows], 0.01 * ticks, atol=F.SPEED_SCALE / 2 + 1e-9)
    status_rows = block.kind == F.FrameKind.CONTROLLER_STATUS
    assert block.status_tick[status_rows].tolist() == list(range(0, N_TICKS, STATUS_EVERY))


def _start_sender(link: str) -> subprocess.Popen:
    return subprocess.Popen(
        [sys.executable, "-c", SENDER, link, str(N_TICKS), str(JOINTS), str(STATUS_EVERY)],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
    )


def test_two_processes_exchange_protected_frames_over_slcan_pty():
    with PtyPair() as pty:
        receiver = open_bus(f"slcan:{pty.b}")
        try:
            _receive_and_check(receiver, _start_sender(f"slcan:{pty.a}"))
        finally:
            receiver.shutdown()
        assert pty.dropped_bytes == 0


def test_two_processes_exchange_protected_frames_over_slcan_tcp_hub():
    hub = subprocess.Popen([str(Path(sys.executable).parent / "edge-monitor"), "slcan-hub", "--port", "0"],
                           stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        banner = hub.stdout.readline().split()
        assert banner[:1] == ["listening"], banner
        link = f"slcan:socket://{banner[1]}"
        receiver = open_bus(link)
        try:
            _receive_and_check(receiver, _start_sender(link))
        finally:
            receiver.shutdown()
    finally:
        hub.terminate()
        hub.communicate(timeout=DEADLINE_S)
    assert hub.returncode == 0


@pytest.mark.skipif(not vcan_available("vcan0"),
                    reason="no SocketCAN vcan0 on this host (kernel lacks vcan or interface not up); "
                           "`ip link add dev vcan0 type vcan && ip link set up vcan0` enables this test")
def test_two_processes_exchange_protected_frames_over_socketcan_vcan0():
    receiver = open_bus("socketcan:vcan0")
    try:
        _receive_and_check(receiver, _start_sender("socketcan:vcan0"))
    finally:
        receiver.shutdown()


def test_virtual_bus_round_trip():
    name = f"virtual:test-{uuid.uuid4().hex}"
    sender, receiver = open_bus(name), open_bus(name)
    try:
        frames = [(F.CONTROLLER_STATUS_ID, F.encode_controller_status(3, F.Mode.PRODUCTION, 9, 200, 123))]
        frames += [(F.MOTOR_STATE_BASE_ID + j, F.encode_motor_state(j, 77, 0.25, -3.5, 1.0)) for j in range(6)]
        for arbitration_id, data in frames:
            sender.send(F.to_message(arbitration_id, data))
        got = [receiver.recv(timeout=5.0) for _ in frames]
    finally:
        sender.shutdown()
        receiver.shutdown()
    assert [(m.arbitration_id, bytes(m.data)) for m in got] == frames
    decoded = [F.decode_message(m) for m in got]
    assert decoded[0] == F.ControllerStatus(3, F.Mode.PRODUCTION, 9, 200, 123)
    assert all(isinstance(d, F.MotorState) and d.tick == 77 for d in decoded[1:])


def test_python_can_configuration_is_used_when_no_link(monkeypatch):
    channel = f"cfg-{uuid.uuid4().hex}"
    monkeypatch.setenv("CAN_INTERFACE", "virtual")
    monkeypatch.setenv("CAN_CHANNEL", channel)
    configured = open_bus(None)
    explicit = open_bus(f"virtual:{channel}")
    try:
        explicit.send(F.to_message(0x100, F.encode_motor_state(0, 1, 0, 0, 0)))
        msg = configured.recv(timeout=5.0)
    finally:
        configured.shutdown()
        explicit.shutdown()
    assert msg is not None and msg.arbitration_id == 0x100
    # explicit arguments win over the environment
    other = open_bus(None, interface="virtual", channel="explicit-channel")
    try:
        assert "explicit-channel" in other.channel_info
    finally:
        other.shutdown()


def test_canrc_file_and_config_context_are_used_when_no_link(tmp_path, monkeypatch):
    for key in ("CAN_INTERFACE", "CAN_CHANNEL", "CAN_BITRATE", "CAN_CONFIG"):
        monkeypatch.delenv(key, raising=False)
    monkeypatch.setenv("HOME", str(tmp_path))
    (tmp_path / ".canrc").write_text(
        "[default]\ninterface = virtual\nchannel = from-canrc\n\n[bench]\ninterface = virtual\nchannel = ctx\n")
    for options, expected in (({}, "from-canrc"), ({"config_context": "bench"}, "ctx")):
        bus = open_bus(None, **options)
        try:
            assert expected in bus.channel_info
        finally:
            bus.shutdown()


@pytest.mark.parametrize(
    ("link", "reason"),
    [
        ("slcan:/dev/pts/99999", "slcan:/dev/pts/99999: device not found"),
        ("bogus:x", "bogus:x: unknown link"),
        ("virtual:", "missing channel"),
        ("socketcan:nosuchcan0", "socketcan:nosuchcan0: "),
        ("replay.blf", "log file is not a bus"),
    ],
)
def test_link_errors_say_which_link_and_why(link, reason):
    with pytest.raises(LinkError, match=reason) as info:
        open_bus(link)
    assert isinstance(info.value, ValueError)


def test_is_log_file():
    assert all(is_log_file(p) for p in ("a.blf", "b.LOG", "c.asc", "d.csv", "e.trc", "f.log.gz"))
    assert not any(is_log_file(p) for p in ("slcan:/dev/pts/3", "virtual:x.log", "socketcan:vcan0", None, "x.txt"))


def test_vcan_available_never_raises():
    assert vcan_available("vcan0") in (True, False)
    assert vcan_available("no-such-interface-name-that-is-too-long") is False


@pytest.mark.parametrize("suffix", [".blf", ".log", ".asc"])
def test_log_write_read_round_trip(tmp_path, suffix):
    ticks = np.arange(500)
    rows = F.encode_motor_state_block(ticks % 6, ticks, np.cos(ticks / 9.0), 30 * np.sin(ticks / 17.0), ticks * 0.01)
    messages = [F.to_message(F.MOTOR_STATE_BASE_ID + int(t % 6), rows[i].tobytes(), timestamp=100.0 + t * 0.0005)
                for i, t in enumerate(ticks)]
    messages.append(F.to_message(F.CONTROLLER_STATUS_ID, F.encode_controller_status(1, 1, 2, 3, 4), timestamp=100.3))
    path = tmp_path / f"frames{suffix}"
    writer = open_log_writer(path)
    for msg in messages:
        writer.on_message_received(msg)
    writer.stop()
    read = list(open_log_reader(path))
    assert len(read) == len(messages)
    assert all(not m.is_extended_id for m in read)
    ids, data, dlc, timestamps = F.messages_to_arrays(read)
    assert ids.tolist() == [m.arbitration_id for m in messages]
    assert np.array_equal(data, np.vstack([rows, np.frombuffer(messages[-1].data, np.uint8)]))
    block = F.decode_block(ids, data, dlc)
    assert block.valid.all()
    intervals = np.diff(timestamps)  # ASC stores relative time; intervals survive in every format
    np.testing.assert_allclose(intervals, np.diff([m.timestamp for m in messages]), atol=2e-5)


def test_log_reader_errors(tmp_path):
    with pytest.raises(LinkError, match="not found"):
        open_log_reader(tmp_path / "missing.blf")
    with pytest.raises(LinkError, match="not a CAN log file"):
        open_log_writer(tmp_path / "frames.txt")


def test_pty_pair_bridges_both_ways_and_closes_cleanly():
    import os

    with PtyPair() as pty:
        fd_a = os.open(pty.a, os.O_RDWR | os.O_NOCTTY)
        fd_b = os.open(pty.b, os.O_RDWR | os.O_NOCTTY)
        try:
            os.write(fd_a, b"t1008" + b"00" * 8 + b"\r")
            assert _read_exactly(fd_b, 22) == b"t1008" + b"00" * 8 + b"\r"
            os.write(fd_b, b"\x00\xff\r\n")  # raw: bytes pass unchanged, no echo
            assert _read_exactly(fd_a, 4) == b"\x00\xff\r\n"
        finally:
            os.close(fd_a)
            os.close(fd_b)
    assert not pty._thread.is_alive()


def _read_exactly(fd: int, size: int, timeout_s: float = 10.0) -> bytes:
    import os
    import select

    buffer = b""
    deadline = time.monotonic() + timeout_s
    while len(buffer) < size and time.monotonic() < deadline:
        ready, _, _ = select.select([fd], [], [], 0.2)
        if ready:
            buffer += os.read(fd, size - len(buffer))
    return buffer


def _wait_for(condition, timeout_s: float = 30.0) -> bool:
    deadline = time.monotonic() + timeout_s
    while not condition() and time.monotonic() < deadline:
        time.sleep(0.01)
    return condition()


def _read_available(fd: int, settle_s: float = 0.3) -> bytes:
    """Everything readable from ``fd`` until nothing new came for ``settle_s`` seconds."""
    import os
    import select

    buffer = b""
    while select.select([fd], [], [], settle_s)[0]:
        chunk = os.read(fd, 65536)
        if not chunk:
            break
        buffer += chunk
    return buffer


def test_pty_pair_does_not_deliver_bytes_sent_before_the_receiver_opened():
    import os

    stale = b"stale\r" * 10_000  # more than the kernel's pty buffers hold
    with PtyPair() as pty:
        fd_a = os.open(pty.a, os.O_RDWR | os.O_NOCTTY)
        try:
            os.write(fd_a, stale)
            assert _wait_for(lambda: pty.discarded_bytes >= len(stale)), pty.discarded_bytes
            fd_b = os.open(pty.b, os.O_RDWR | os.O_NOCTTY)  # no flush on open: the bridge must not deliver
            try:
                os.write(fd_a, b"fresh\r")
                assert _read_exactly(fd_b, 6) == b"fresh\r"
                assert _read_available(fd_b) == b""
            finally:
                os.close(fd_b)
        finally:
            os.close(fd_a)
        assert pty.discarded_bytes == len(stale) and pty.dropped_bytes == 0


_WRITE_AND_EXIT = "import os, sys\nfd = os.open(sys.argv[1], os.O_WRONLY | os.O_NOCTTY)\nos.write(fd, sys.argv[2].encode())\n"


def test_pty_pair_learns_of_opens_and_closes_at_once_without_polling():
    """Another process writes before the receiver opens and exits: with inotify the bridge learns of
    it at once and discards its bytes (the poll fallback is set to an hour here, so only inotify can
    wake the bridge); a receiver opened after that gets only what is written later, by another process."""
    import os
    import subprocess
    import sys

    with PtyPair(poll_interval=3600.0) as pty:
        if pty._inotify < 0:
            pytest.skip("no inotify on this system: the bridge polls every poll_interval")
        stale = "stale\r" * 1000
        subprocess.run([sys.executable, "-c", _WRITE_AND_EXIT, pty.a, stale], check=True, timeout=60)
        assert _wait_for(lambda: pty.discarded_bytes == len(stale)), pty.discarded_bytes
        fd_b = os.open(pty.b, os.O_RDWR | os.O_NOCTTY)
        try:
            subprocess.run([sys.executable, "-c", _WRITE_AND_EXIT, pty.a, "fresh\r"], check=True, timeout=60)
            assert _read_exactly(fd_b, 6) == b"fresh\r"
            assert _read_available(fd_b) == b""
        finally:
            os.close(fd_b)
        assert pty.discarded_bytes == len(stale) and pty.dropped_bytes == 0


def test_pty_pair_drops_unread_bytes_when_the_receiver_closes():
    import os

    with PtyPair() as pty:
        fd_a = os.open(pty.a, os.O_RDWR | os.O_NOCTTY)
        try:
            fd_b = os.open(pty.b, os.O_RDWR | os.O_NOCTTY)
            os.write(fd_a, b"read\r")
            assert _read_exactly(fd_b, 5) == b"read\r"
            os.write(fd_a, b"unread\r")
            assert _wait_for(lambda: not pty._pending[pty._master_b]), "bridge did not forward"
            os.close(fd_b)                        # closes with 7 bytes unread
            assert _wait_for(lambda: pty.discarded_bytes == 7), pty.discarded_bytes
            fd_b = os.open(pty.b, os.O_RDWR | os.O_NOCTTY)
            try:
                os.write(fd_a, b"again\r")
                assert _read_exactly(fd_b, 6) == b"again\r"
                assert _read_available(fd_b) == b""
            finally:
                os.close(fd_b)
        finally:
            os.close(fd_a)


def test_pty_pair_forwards_what_a_short_lived_writer_sent():
    import os

    with PtyPair() as pty:
        fd_b = os.open(pty.b, os.O_RDWR | os.O_NOCTTY)
        try:
            fd_a = os.open(pty.a, os.O_WRONLY | os.O_NOCTTY)
            os.write(fd_a, b"bye\r")
            os.close(fd_a)                        # before the bridge noticed the end was open
            assert _read_exactly(fd_b, 4) == b"bye\r"
        finally:
            os.close(fd_b)
        assert pty.discarded_bytes == 0


class _Recorder:
    """A PtyObserver that keeps what it is told."""

    def __init__(self) -> None:
        self.events: list[tuple] = []

    def queued(self, end, data):
        self.events.append(("queued", end, bytes(data)))

    def lost(self, end, data, reason):
        self.events.append(("lost", end, bytes(data), reason))

    def undelivered(self, end, start, stop):
        self.events.append(("undelivered", end, start, stop))

    def closed(self, end):
        self.events.append(("closed", end))


def test_pty_pair_observer_is_told_the_fate_of_every_byte():
    import os

    seen = _Recorder()
    with PtyPair(observer=seen) as pty:
        fd_a = os.open(pty.a, os.O_RDWR | os.O_NOCTTY)
        try:
            os.write(fd_a, b"early\r")                   # nobody has .b open: lost
            assert _wait_for(lambda: pty.discarded_bytes == 6 and pty.backlog() == 0)
            fd_b = os.open(pty.b, os.O_RDWR | os.O_NOCTTY)
            os.write(fd_a, b"read\r")
            assert _read_exactly(fd_b, 5) == b"read\r"
            os.write(fd_a, b"unread\r")
            assert _wait_for(lambda: ("queued", pty.b, b"unread\r") in seen.events and pty.backlog() == 0)
            os.close(fd_b)                                # 7 queued bytes never read
            assert _wait_for(lambda: ("closed", pty.b) in seen.events), seen.events
        finally:
            os.close(fd_a)
    to_b = [e for e in seen.events if e[1] == pty.b]
    assert to_b[0] == ("lost", pty.b, b"early\r", "closed")
    assert b"".join(e[2] for e in to_b if e[0] == "queued") == b"read\runread\r"
    assert to_b[-2:] == [("undelivered", pty.b, 5, 12), ("closed", pty.b)]
