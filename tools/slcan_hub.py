#!/usr/bin/env python3
"""Loopback TCP hub for slcan: every byte a client sends is relayed to all other clients.

So ``slcan:socket://127.0.0.1:PORT`` works as a shared "bus" between processes on machines
without SocketCAN (a simulator and an agent, plus e.g. ``cantools monitor``).

Usage: ``python tools/slcan_hub.py [--port 0]`` prints ``listening 127.0.0.1:PORT`` and runs
until interrupted.  Binds 127.0.0.1 only.  A client that stops reading gets at most
``--max-buffer`` bytes queued; beyond that its bytes are dropped and counted (logged on exit).
"""

from __future__ import annotations

import argparse
import logging
import selectors
import signal
import socket
import sys

log = logging.getLogger("slcan_hub")


class SlcanHub:
    """Byte relay between all TCP clients connected to 127.0.0.1:port."""

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


def main() -> None:
    parser = argparse.ArgumentParser(description="Loopback TCP hub relaying slcan bytes between clients")
    parser.add_argument("--port", type=int, default=0, help="TCP port on 127.0.0.1 (0 = pick a free one)")
    parser.add_argument("--max-buffer", type=int, default=1 << 20, help="bytes queued per slow client")
    args = parser.parse_args()
    logging.basicConfig(level=logging.INFO, format="%(name)s: %(message)s")
    hub = SlcanHub(args.port, args.max_buffer)
    signal.signal(signal.SIGTERM, lambda *_: hub.stop())
    print(f"listening 127.0.0.1:{hub.port}", flush=True)
    try:
        hub.serve_forever()
    except KeyboardInterrupt:
        pass
    finally:
        hub.close()
    sys.exit(0)


if __name__ == "__main__":
    main()
