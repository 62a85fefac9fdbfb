"""A bridged pair of pseudo-terminals: a null-modem cable between two slcan ends without SocketCAN
(docs/PROTOCOL.md, "Links"). Also importable from :mod:`protocol.links`."""

from __future__ import annotations

import fcntl
import logging
import os
import select
import struct
import termios
import threading
import tty
from typing import Protocol

log = logging.getLogger(__name__)

_IN_OPEN, _IN_CLOSE_WRITE, _IN_CLOSE_NOWRITE, _IN_NONBLOCK, _IN_CLOEXEC = 0x20, 0x08, 0x10, 0o4000, 0o2000000


def _watch_open_close(paths: list[str]) -> int:
    """An inotify descriptor that becomes readable whenever one of ``paths`` is opened or closed
    (Linux; devpts reports both), or -1 where inotify is not available."""
    try:
        import ctypes

        libc = ctypes.CDLL(None, use_errno=True)
        fd = libc.inotify_init1(_IN_NONBLOCK | _IN_CLOEXEC)
    except (OSError, AttributeError):
        return -1
    if fd < 0:
        return -1
    mask = _IN_OPEN | _IN_CLOSE_WRITE | _IN_CLOSE_NOWRITE
    if any(libc.inotify_add_watch(fd, path.encode(), mask) < 0 for path in paths):
        os.close(fd)
        return -1
    return fd


def _drain_events(fd: int) -> None:
    try:
        while os.read(fd, 65536):
            pass
    except OSError:          # EAGAIN: all read
        pass


class PtyObserver(Protocol):
    """What a :class:`PtyPair` tells about the bytes travelling towards each end (``end`` is the
    end's path, ``.a`` or ``.b``). Called on the bridge thread, in the order things happen: keep
    the methods quick (e.g. append to a queue)."""

    def queued(self, end: str, data: bytes) -> None:
        """``data`` was accepted for ``end``'s user; in stream order: byte ``n`` of the concatenation of
        every ``queued`` call for ``end`` is its stream position ``n``."""

    def lost(self, end: str, data: bytes, reason: str) -> None:
        """``data`` for ``end`` was dropped before it was queued; ``reason``: "closed" (no user had
        ``end`` open) or "overflow" (``max_buffer`` reached)."""

    def undelivered(self, end: str, start: int, stop: int) -> None:
        """Queued bytes ``[start, stop)`` of ``end``'s stream never reached a user (still unread
        when its user closed it, or a write error)."""

    def closed(self, end: str) -> None:
        """``end``'s last user closed it (after the matching :meth:`undelivered`)."""


class PtyPair:
    """Two pseudo-terminals bridged both ways: bytes written to ``.a`` are read from ``.b`` and
    vice versa.  Each end behaves like one side of a null-modem cable, so two processes can talk
    slcan (``slcan:`` + ``.a`` / ``.b``) without SocketCAN.

    Like a serial line, an end delivers only bytes sent while it is open: bytes written to one end
    while the other end is not open anywhere are discarded (``discarded_bytes``), and so are bytes
    still unread in an end when its last user closes it.  So open the receiving end before the peer
    starts sending.  The bridge learns that an end was opened or closed from inotify at once (on
    Linux; elsewhere, or if inotify is unavailable, within ``poll_interval`` seconds) and moves bytes
    as soon as they are written, so a byte written before the receiver opened is delivered only if
    the bridge thread had no chance to run between the write and the open (e.g. a writer and a
    receiver in the bridge's own process, holding the GIL).
    Bytes written while the other end is open but not read are buffered up to ``max_buffer``
    bytes per direction, then dropped and counted in ``dropped_bytes``.
    Use as a context manager; ``close()`` stops the bridge thread and closes all descriptors.
    ``observer`` (a :class:`PtyObserver`) is told the fate of every byte, e.g. to count frames per
    receiving process; ``backlog()`` says how many bytes the bridge has still to move.
    """

    def __init__(self, max_buffer: int = 1 << 20, poll_interval: float = 0.02,
                 observer: PtyObserver | None = None) -> None:
        self.max_buffer = max_buffer
        self.poll_interval = poll_interval
        self.observer = observer
        self.dropped_bytes = 0
        self.discarded_bytes = 0
        self._master_a, slave_a = os.openpty()
        self._master_b, slave_b = os.openpty()
        for fd in (slave_a, slave_b):
            tty.setraw(fd)  # no echo, no line discipline: bytes pass unchanged (kept after close)
        self.a: str = os.ttyname(slave_a)
        self.b: str = os.ttyname(slave_b)
        # Only users hold the slaves open, so a master reports POLLHUP while its end is closed.
        os.close(slave_a)
        os.close(slave_b)
        for fd in (self._master_a, self._master_b):
            os.set_blocking(fd, False)
        self._path = {self._master_a: self.a, self._master_b: self.b}
        self._peer = {self._master_a: self._master_b, self._master_b: self._master_a}
        self._pending = {self._master_a: bytearray(), self._master_b: bytearray()}  # waiting to be written
        self._open = {self._master_a: False, self._master_b: False}
        self._queued = {self._master_a: 0, self._master_b: 0}                        # stream positions
        self._hangups = select.poll()
        for fd in self._peer:
            self._hangups.register(fd, 0)  # POLLHUP is always reported
        self._wake_read, self._wake_write = os.pipe()
        self._inotify = _watch_open_close([self.a, self.b])   # -1: poll every poll_interval instead
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._bridge, name=f"PtyPair {self.a}<->{self.b}", daemon=True)
        self._thread.start()

    def __enter__(self) -> PtyPair:
        return self

    def __exit__(self, *exc_info: object) -> None:
        self.close()

    def _closed_ends(self) -> set[int]:
        return {fd for fd, events in self._hangups.poll(0) if events & (select.POLLHUP | select.POLLERR)}

    def _update_ends(self) -> None:
        """Track which ends are open; an end that was just closed is cleaned up."""
        closed = self._closed_ends()
        for fd in self._peer:
            now_open = fd not in closed
            if self._open[fd] and not now_open:
                self._end_closed(fd)
            elif not now_open:
                self._read_from(fd)               # a user opened, wrote and closed in between
            self._open[fd] = now_open

    def is_open(self, end: str) -> bool:
        """Whether a user holds ``end`` (``.a`` or ``.b``) open, as the bridge last saw it: e.g. wait for
        the receiver before sending."""
        return any(self._open[fd] for fd, path in self._path.items() if path == end)

    def backlog(self) -> int:
        """Bytes written by the users that the bridge has not moved yet (unread by the bridge, or
        queued for an end and not yet written to it). The kernel hands what a user writes to the bridge's
        side asynchronously: right after a write this can still be 0."""
        unread = 0
        for fd in self._peer:
            try:
                unread += struct.unpack("i", fcntl.ioctl(fd, termios.FIONREAD, b"\0\0\0\0"))[0]
            except OSError:
                pass
        return unread + sum(len(p) for p in self._pending.values())

    def _end_closed(self, fd: int) -> None:
        self._read_from(fd)                       # what the closing user wrote last still goes over
        unwritten = len(self._pending[fd])
        self.discarded_bytes += unwritten
        self._pending[fd].clear()
        unread = self._drain(fd)                  # bytes the user did not read: drop them now
        self.discarded_bytes += unread
        if self.observer is not None:
            end = self._queued[fd]
            self.observer.undelivered(self._path[fd], end - unwritten - unread, end)
            self.observer.closed(self._path[fd])

    def _drain(self, fd: int) -> int:
        """Read and drop what waits unread in ``fd``'s end; the number of bytes."""
        drained = 0
        try:
            slave = os.open(self._path[fd], os.O_RDWR | os.O_NOCTTY | os.O_NONBLOCK)
        except OSError:
            return 0
        try:
            while chunk := os.read(slave, 65536):
                drained += len(chunk)
        except OSError:
            pass
        finally:
            os.close(slave)
        return drained

    def _read_from(self, fd: int) -> None:
        """Move what ``fd``'s user wrote towards the peer (or discard it if the peer is closed)."""
        while True:
            try:
                chunk = os.read(fd, 65536)
            except OSError:  # EAGAIN: nothing more; EIO: the end is closed and drained
                return
            if not chunk:
                return
            peer = self._peer[fd]
            if peer in self._closed_ends():
                self.discarded_bytes += len(chunk)
                self._tell_lost(peer, chunk, "closed")
                continue
            target = self._pending[peer]
            room = max(self.max_buffer - len(target), 0)
            if len(chunk) > room:
                self.dropped_bytes += len(chunk) - room
                self._tell_lost(peer, chunk[room:], "overflow")
                chunk = chunk[:room]
            target += chunk
            self._queued[peer] += len(chunk)
            if self.observer is not None and chunk:
                self.observer.queued(self._path[peer], chunk)
            self._write_to(peer)

    def _tell_lost(self, fd: int, data: bytes, reason: str) -> None:
        if self.observer is not None and data:
            self.observer.lost(self._path[fd], data, reason)

    def _write_to(self, fd: int) -> None:
        pending = self._pending[fd]
        try:
            del pending[:os.write(fd, pending)]
        except BlockingIOError:
            pass
        except OSError:
            self.discarded_bytes += len(pending)
            if self.observer is not None and pending:
                self.observer.undelivered(self._path[fd], self._queued[fd] - len(pending), self._queued[fd])
            pending.clear()

    def _bridge(self) -> None:
        poller = select.poll()
        poller.register(self._wake_read, select.POLLIN)
        if self._inotify >= 0:
            poller.register(self._inotify, select.POLLIN)
        registered: dict[int, int] = {}
        while not self._stop.is_set():
            self._update_ends()
            for fd, is_open in self._open.items():
                events = (select.POLLIN | (select.POLLOUT if self._pending[fd] else 0)) if is_open else 0
                if registered.get(fd) != events:
                    if events:
                        poller.register(fd, events)  # (re-)registering replaces the event mask
                    elif fd in registered:
                        poller.unregister(fd)
                    registered[fd] = events
            timeout = 1.0 if all(self._open.values()) else self.poll_interval
            try:
                ready = poller.poll(timeout * 1000.0)
            except (OSError, ValueError):
                return
            for fd, events in ready:
                if fd == self._wake_read:
                    return
                if fd == self._inotify:         # an end was opened or closed: the next pass looks
                    _drain_events(fd)
                    continue
                if events & select.POLLOUT:
                    self._write_to(fd)
                if events & select.POLLIN:
                    self._read_from(fd)

    def close(self) -> None:
        """Stop the bridge and close every descriptor (idempotent)."""
        if self._stop.is_set():
            return
        self._stop.set()
        try:
            os.write(self._wake_write, b"x")
        except OSError:
            pass
        self._thread.join(timeout=5.0)
        for fd in (self._master_a, self._master_b, self._wake_read, self._wake_write, self._inotify):
            if fd < 0:
                continue
            try:
                os.close(fd)
            except OSError:
                pass
        if self.dropped_bytes:
            log.warning("PtyPair dropped %d bytes (peer not reading)", self.dropped_bytes)
