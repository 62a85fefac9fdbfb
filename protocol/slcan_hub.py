"""Loopback TCP hub for slcan: every Lawicel line a client sends is relayed to all other clients.

So ``slcan:socket://127.0.0.1:PORT`` works as a shared "bus" between processes on machines without
SocketCAN (a simulator and an agent, plus e.g. ``cantools monitor``); ``edge-monitor slcan-hub`` runs
one. Binds 127.0.0.1 only.

The hub relays whole lines (up to a ``\\r``/``\\a`` terminator), never part of one, and nothing is
lost uncounted (:class:`HubStats`): a client that stops reading gets at most ``max_buffer`` bytes
queued; the frames that do not fit are dropped for that client and counted (``dropped_frames``); frames
still queued for a client when it disconnects or the hub closes are counted (``undelivered_frames``);
input lines longer than :data:`MAX_LINE_LENGTH` (terminator included) and a line cut off by a
disconnect are dropped and counted (``malformed_lines``), so a client's garbage never reaches the
others. ``close()`` logs the totals.
"""

from __future__ import annotations

import logging
import re
import selectors
import socket
from dataclasses import dataclass, field

from protocol.slcan_fast import MAX_LINE_LENGTH

log = logging.getLogger(__name__)

#: A line longer than the longest slcan line (terminator included): garbage, never relayed.
_OVERLONG = re.compile(rb"[^\r\a]{%d,}[\r\a]" % MAX_LINE_LENGTH)

#: Drops for one client are logged at the first one and then every this many frames.
WARN_EVERY_FRAMES = 10_000


def _line_end(data: bytes | bytearray, limit: int) -> int:
    """Length of the longest prefix of ``data[:limit]`` made of whole lines (0: none)."""
    return max(data.rfind(b"\r", 0, limit), data.rfind(b"\a", 0, limit)) + 1


def _first_line_end(data: bytes | bytearray) -> int:
    """Length of ``data``'s first line including its terminator (0: no terminator)."""
    ends = [i for i in (data.find(b"\r"), data.find(b"\a")) if i >= 0]
    return min(ends) + 1 if ends else 0


def count_lines(data: bytes | bytearray) -> int:
    """Terminated Lawicel lines (frames, commands, replies) in ``data``."""
    return data.count(b"\r") + data.count(b"\a")


@dataclass
class HubStats:
    """What the hub moved and every discard, in frames (Lawicel lines) and bytes."""

    clients: int = 0                 # connections accepted so far
    frames_in: int = 0               # whole lines (frames and slcan commands) received from clients
    dropped_frames: int = 0          # not queued for a client whose queue was full (summed over clients)
    dropped_bytes: int = 0
    undelivered_frames: int = 0      # queued for a client that disconnected (or at close) before it got them
    malformed_lines: int = 0         # longer than MAX_LINE_LENGTH, or cut off by a disconnect
    malformed_bytes: int = 0

    @property
    def lost_frames(self) -> int:
        """Frames some client did not get: dropped plus undelivered."""
        return self.dropped_frames + self.undelivered_frames

    def summary(self) -> str:
        """One line for the log at exit."""
        text = f"received {self.frames_in} frames from {self.clients} clients"
        if self.lost_frames:
            text += (f"; lost {self.lost_frames} frames for clients: {self.dropped_frames} dropped "
                     f"({self.dropped_bytes} bytes) because a client did not read and its queue was full, "
                     f"{self.undelivered_frames} still queued when a client left or the hub stopped")
        if self.malformed_lines:
            text += (f"; dropped {self.malformed_lines} malformed input lines ({self.malformed_bytes} bytes: "
                     f"longer than {MAX_LINE_LENGTH} bytes, or cut off by a disconnect)")
        return text


@dataclass(eq=False)
class _Client:
    """One connection: what waits to be sent to it, and its unfinished input line."""

    sock: socket.socket
    address: str
    out: bytearray = field(default_factory=bytearray)
    partial: bytearray = field(default_factory=bytearray)   # input after its last terminator
    discarding: bool = False                                # inside an overlong input line
    dropped_frames: int = 0


class SlcanHub:
    """Line relay between all TCP clients connected to 127.0.0.1:port (0: a free port, see ``port``)."""

    def __init__(self, port: int = 0, max_buffer: int = 1 << 20) -> None:
        if max_buffer < MAX_LINE_LENGTH:
            raise ValueError(f"max_buffer {max_buffer}: must be ≥ {MAX_LINE_LENGTH} bytes (the longest slcan line)")
        self.max_buffer = max_buffer
        self.stats = HubStats()
        self._selector = selectors.DefaultSelector()
        self._server = socket.create_server(("127.0.0.1", port))
        self._server.setblocking(False)
        self.port: int = self._server.getsockname()[1]
        self._selector.register(self._server, selectors.EVENT_READ)
        self._clients: dict[socket.socket, _Client] = {}
        self._running = True
        self._closed = False

    @property
    def dropped_bytes(self) -> int:
        return self.stats.dropped_bytes

    @property
    def connected(self) -> int:
        """Clients connected now."""
        return len(self._clients)

    def serve_forever(self) -> None:
        while self._running:
            for key, events in self._selector.select(timeout=0.5):
                if key.fileobj is self._server:
                    self._accept()
                    continue
                client = self._clients.get(key.fileobj)     # type: ignore[call-overload]
                if client is not None and events & selectors.EVENT_READ:
                    self._relay_from(client)
                if client is not None and events & selectors.EVENT_WRITE and client.sock in self._clients:
                    self._flush(client)

    def stop(self) -> None:
        self._running = False

    def close(self) -> None:
        """Disconnect every client (counting what was still queued for it) and log the totals (idempotent)."""
        if self._closed:
            return
        self._closed = True
        for client in list(self._clients.values()):
            self._flush(client)
            self._disconnect(client, "the hub stopped")
        self._selector.unregister(self._server)
        self._server.close()
        self._selector.close()
        lost = self.stats.lost_frames or self.stats.malformed_lines
        log.log(logging.WARNING if lost else logging.INFO, "slcan hub: %s", self.stats.summary())

    def _accept(self) -> None:
        try:
            conn, address = self._server.accept()
        except (BlockingIOError, InterruptedError):
            return
        conn.setblocking(False)
        conn.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        self._clients[conn] = _Client(conn, f"{address[0]}:{address[1]}")
        self.stats.clients += 1
        self._selector.register(conn, selectors.EVENT_READ)
        log.info("client %s:%s connected (%d clients)", *address[:2], len(self._clients))

    def _relay_from(self, client: _Client) -> None:
        try:
            chunk = client.sock.recv(65536)
        except (BlockingIOError, InterruptedError):
            return
        except OSError:
            chunk = b""
        if not chunk:
            self._disconnect(client, "it closed the connection")
            return
        lines = self._whole_lines(client, chunk)
        if not lines:
            return
        frames = count_lines(lines)
        self.stats.frames_in += frames
        for peer in list(self._clients.values()):
            if peer is not client and peer.sock in self._clients:
                self._queue(peer, lines, frames)

    def _whole_lines(self, client: _Client, chunk: bytes) -> bytes:
        """The whole lines that ``chunk`` completes; its unfinished tail waits in ``client.partial``."""
        end = _line_end(chunk, len(chunk))
        head = chunk[:end]
        if end and client.discarding:             # the rest of an overlong line: drop it
            first = _first_line_end(head)
            self.stats.malformed_bytes += first
            client.discarding = False
            head = head[first:]
        elif end and client.partial:
            head = bytes(client.partial) + head
            client.partial.clear()
        self._keep_tail(client, chunk[end:])
        return self._without_overlong(client, head) if _OVERLONG.search(head) else head

    def _without_overlong(self, client: _Client, lines: bytes) -> bytes:
        """``lines`` without those longer than :data:`MAX_LINE_LENGTH` (counted)."""
        kept, start = [], 0
        for match in _OVERLONG.finditer(lines):
            kept.append(lines[start:match.start()])
            self._count_malformed(client, match.end() - match.start(), "longer than any slcan line")
            start = match.end()
        kept.append(lines[start:])
        return b"".join(kept)

    def _keep_tail(self, client: _Client, tail: bytes) -> None:
        if client.discarding:
            self.stats.malformed_bytes += len(tail)
        elif len(client.partial) + len(tail) >= MAX_LINE_LENGTH:     # no room left for a terminator
            self._count_malformed(client, len(client.partial) + len(tail), "longer than any slcan line")
            client.partial.clear()
            client.discarding = True
        else:
            client.partial += tail

    def _count_malformed(self, client: _Client, size: int, why: str) -> None:
        self.stats.malformed_lines += 1
        self.stats.malformed_bytes += size
        if self.stats.malformed_lines == 1 or self.stats.malformed_lines % 1000 == 0:
            log.warning("client %s: dropped a malformed input line of %d+ bytes (%s; %d so far): is it "
                        "speaking slcan?", client.address, size, why, self.stats.malformed_lines)

    def _queue(self, peer: _Client, lines: bytes, frames: int) -> None:
        """Queue ``lines`` for ``peer``; the whole lines beyond its ``max_buffer`` are dropped and counted."""
        room = self.max_buffer - len(peer.out)
        fits = lines if len(lines) <= room else lines[:_line_end(lines, max(room, 0))]
        if len(fits) < len(lines):
            self._count_dropped(peer, frames - count_lines(fits), len(lines) - len(fits))
        if fits:
            was_empty = not peer.out
            peer.out += fits
            if was_empty:
                self._flush(peer)

    def _count_dropped(self, peer: _Client, frames: int, size: int) -> None:
        before = peer.dropped_frames
        peer.dropped_frames += frames
        self.stats.dropped_frames += frames
        self.stats.dropped_bytes += size
        if before == 0 or before // WARN_EVERY_FRAMES != peer.dropped_frames // WARN_EVERY_FRAMES:
            log.warning("client %s does not read fast enough: its queue of %d bytes is full, %d frames dropped "
                        "for it so far (counted, totals logged at exit)", peer.address, self.max_buffer,
                        peer.dropped_frames)

    def _flush(self, client: _Client) -> None:
        try:
            sent = client.sock.send(client.out)
            del client.out[:sent]
        except (BlockingIOError, InterruptedError):
            pass
        except OSError:
            self._disconnect(client, "sending to it failed")
            return
        self._selector.modify(client.sock, selectors.EVENT_READ | (selectors.EVENT_WRITE if client.out else 0))

    def _disconnect(self, client: _Client, why: str) -> None:
        """Forget ``client``, counting the frames still queued for it and its unfinished input line."""
        if self._clients.pop(client.sock, None) is None:
            return
        undelivered = count_lines(client.out)
        self.stats.undelivered_frames += undelivered
        if client.partial:
            self._count_malformed(client, len(client.partial), "cut off by the disconnect")
        try:
            self._selector.unregister(client.sock)
        except (KeyError, ValueError):
            pass
        client.sock.close()
        lost = client.dropped_frames + undelivered
        log.log(logging.WARNING if lost else logging.INFO,
                "client %s disconnected (%s): %d frames dropped for it, %d still queued; %d clients left",
                client.address, why, client.dropped_frames, undelivered, len(self._clients))
