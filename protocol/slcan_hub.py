"""Loopback TCP hub for slcan: every byte a client sends is relayed to all other clients.

So ``slcan:socket://127.0.0.1:PORT`` works as a shared "bus" between processes on machines without
SocketCAN (a simulator and an agent, plus e.g. ``cantools monitor``); ``edge-monitor slcan-hub`` runs
one. Binds 127.0.0.1 only. A client that stops reading gets at most ``max_buffer`` bytes queued; beyond
that its bytes are dropped and counted (``dropped_bytes``).
"""

from __future__ import annotations

import logging
import selectors
import socket

log = logging.getLogger(__name__)


class SlcanHub:
    """Byte relay between all TCP clients connected to 127.0.0.1:port (0: a free port, see ``port``)."""

    def __init__(self, port: int = 0, max_buffer: int = 1 << 20) -> None:
        self.max_buffer = max_buffer
        self.dropped_bytes = 0
        self._selector = selectors.DefaultSelector()
        self._server = socket.create_server(("127.0.0.1", port))
        self._server.setblocking(False)
        self.port: int = self._server.getsockname()[1]
        self._selector.register(self._server, selectors.EVENT_READ)
        self._pending: dict[socket.socket, bytearray] = {}
        self._running = True

    def serve_forever(self) -> None:
        while self._running:
            for key, events in self._selector.select(timeout=0.5):
                sock = key.fileobj
                if sock is self._server:
                    self._accept()
                    continue
                assert isinstance(sock, socket.socket)    # the server and accepted connections only
                if events & selectors.EVENT_READ:
                    self._relay_from(sock)
                if events & selectors.EVENT_WRITE and sock in self._pending:
                    self._flush(sock)

    def stop(self) -> None:
        self._running = False

    def close(self) -> None:
        for sock in list(self._pending):
            self._drop(sock)
        self._selector.unregister(self._server)
        self._server.close()
        self._selector.close()
        if self.dropped_bytes:
            log.warning("dropped %d bytes for clients that did not read", self.dropped_bytes)

    def _accept(self) -> None:
        conn, address = self._server.accept()
        conn.setblocking(False)
        conn.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        self._pending[conn] = bytearray()
        self._selector.register(conn, selectors.EVENT_READ)
        log.info("client %s connected (%d clients)", address, len(self._pending))

    def _relay_from(self, sock: socket.socket) -> None:
        try:
            chunk = sock.recv(65536)
        except (BlockingIOError, InterruptedError):
            return
        except OSError:
            chunk = b""
        if not chunk:
            self._drop(sock)
            return
        for peer, buffer in list(self._pending.items()):
            if peer is sock:
                continue
            room = self.max_buffer - len(buffer)
            if len(chunk) > room:
                self.dropped_bytes += len(chunk) - max(room, 0)
            if room > 0:
                was_empty = not buffer
                buffer += chunk[:room]
                if was_empty:
                    self._flush(peer)

    def _flush(self, sock: socket.socket) -> None:
        buffer = self._pending[sock]
        try:
            sent = sock.send(buffer)
            del buffer[:sent]
        except (BlockingIOError, InterruptedError):
            pass
        except OSError:
            self._drop(sock)
            return
        self._selector.modify(sock, selectors.EVENT_READ | (selectors.EVENT_WRITE if buffer else 0))

    def _drop(self, sock: socket.socket) -> None:
        self._pending.pop(sock, None)
        try:
            self._selector.unregister(sock)
        except (KeyError, ValueError):
            pass
        sock.close()
