"""Links: open a python-can bus from a link string, log files, a bridged pty pair, vcan detection.

Link strings (docs/PROTOCOL.md, "Links"):

* ``socketcan:IFACE``            Linux SocketCAN (real or vcan)
* ``slcan:DEVICE_OR_URL``        Lawicel serial-line CAN over a serial device, a pty or any pyserial
                                 URL such as ``socket://127.0.0.1:PORT``
* ``virtual:NAME``               python-can in-process bus (one process only)
* ``None``                       python-can's own configuration (arguments, ``CAN_*`` environment,
                                 ``~/.canrc``); none of them naming an interface raises ``NoCanConfigError``
* a log file (``.blf``, ``.log``, ``.asc``, ``.csv``, ``.trc``) is not a bus: see ``is_log_file``.
"""

from __future__ import annotations

import errno
import fcntl
import logging
import os
import select
import socket
import struct
import termios
import threading
import tty
from pathlib import Path
from typing import Any, Iterable, Protocol

import can

log = logging.getLogger(__name__)

LOG_SUFFIXES = (".blf", ".log", ".asc", ".csv", ".trc", ".log.gz", ".asc.gz")
LINK_SCHEMES = ("socketcan", "slcan", "virtual")


class LinkError(ValueError):
    """A link could not be opened or is malformed; the message starts with the link."""


class NoCanConfigError(LinkError):
    """No link given and python-can's configuration names no interface: the message says what to do."""


NO_CAN_CONFIG = ("no CAN interface configured: pass --link socketcan:IFACE or slcan:/dev/pts/N, -i/--interface "
                 "with -c/--channel, or set CAN_INTERFACE/CAN_CHANNEL or a python-can config file (~/.canrc)")


def is_log_file(link: str | os.PathLike | None) -> bool:
    """True if ``link`` names a CAN log file by its suffix (it need not exist yet)."""
    if link is None:
        return False
    name = str(link).lower()
    if name.split(":", 1)[0] in LINK_SCHEMES:
        return False
    return name.endswith(LOG_SUFFIXES)


def open_log_reader(path: str | os.PathLike) -> Iterable[can.Message]:
    """python-can LogReader for an existing log file (format from the suffix)."""
    if not is_log_file(path):
        raise LinkError(f"{path}: not a CAN log file; use one of {', '.join(LOG_SUFFIXES)}")
    if not Path(path).is_file():
        raise LinkError(f"{path}: log file not found")
    try:
        return can.LogReader(path)
    except Exception as error:  # noqa: BLE001 - re-raised as the typed error
        raise LinkError(f"{path}: cannot read log ({error})") from error


def open_log_writer(path: str | os.PathLike) -> can.Listener:
    """python-can Logger writing a log file (format from the suffix); call ``.stop()`` to close."""
    if not is_log_file(path):
        raise LinkError(f"{path}: not a CAN log file; use one of {', '.join(LOG_SUFFIXES)}")
    try:
        return can.Logger(path)
    except Exception as error:  # noqa: BLE001
        raise LinkError(f"{path}: cannot write log ({error})") from error


def parse_link(link: str) -> tuple[str, str]:
    """``"scheme:channel"`` -> (scheme, channel); raises LinkError naming the link."""
    scheme, sep, channel = str(link).partition(":")
    if not sep or scheme not in LINK_SCHEMES:
        raise LinkError(f"{link}: unknown link; use socketcan:IFACE, slcan:DEVICE_OR_URL, virtual:NAME "
                        "or a log file")
    if not channel:
        raise LinkError(f"{link}: missing channel after '{scheme}:'")
    return scheme, channel


def open_bus(
    link: str | None,
    *,
    interface: str | None = None,
    channel: str | None = None,
    bitrate: int | None = None,
    receive_own_messages: bool = False,
    **kwargs: Any,
) -> can.BusABC:
    """Open a python-can bus from a link string (or python-can's configuration if ``link`` is None).

    Extra keyword arguments go to the python-can interface (e.g. ``sleep_after_open`` for slcan,
    default 0 here).  Failures raise ``LinkError`` saying which link and why.
    """
    if link is None:
        return _open_configured(interface, channel, bitrate, receive_own_messages, kwargs)
    if is_log_file(link):
        raise LinkError(f"{link}: a log file is not a bus; read it with open_log_reader()")
    scheme, target = parse_link(link)
    options: dict[str, Any] = dict(kwargs)
    if bitrate is not None:
        options["bitrate"] = bitrate
    if scheme == "slcan":
        options.setdefault("sleep_after_open", 0)
        if "://" not in target and not target.split("@", 1)[0].startswith("COM") \
                and not os.path.exists(target.split("@", 1)[0]):
            raise LinkError(f"{link}: device not found")
    else:
        options["receive_own_messages"] = receive_own_messages
    try:
        if scheme == "slcan":   # chunked reads: python-can's byte-wise reader starves next to numeric threads
            from protocol.slcan_fast import FastSlcanBus
            return FastSlcanBus(target, **options)
        return can.Bus(interface=scheme, channel=target, ignore_config=True, **options)
    except Exception as error:  # noqa: BLE001 - every interface raises its own types
        raise LinkError(f"{link}: {_reason(error)}") from error


def _open_configured(
    interface: str | None, channel: str | None, bitrate: int | None, receive_own_messages: bool,
    kwargs: dict[str, Any],
) -> can.BusABC:
    options: dict[str, Any] = dict(kwargs)
    for key, value in (("interface", interface), ("channel", channel), ("bitrate", bitrate)):
        if value is not None:
            options[key] = value
    if receive_own_messages:
        options["receive_own_messages"] = True
    described = f"interface={interface or '(config)'} channel={channel or '(config)'}"
    if interface is None and not _interface_configured(options.get("config_context")):
        raise NoCanConfigError(NO_CAN_CONFIG)
    try:
        config = can.util.load_config(config={k: v for k, v in options.items()
                                              if k in ("interface", "channel", "bitrate")},
                                      context=options.get("config_context"))
    except Exception as error:  # noqa: BLE001
        raise LinkError(f"{described}: python-can configuration invalid ({_reason(error)})") from error
    if config.get("interface") == "slcan":
        options.setdefault("sleep_after_open", 0)
    try:
        return can.Bus(**options)
    except Exception as error:  # noqa: BLE001
        raise LinkError(f"{described}: {_reason(error)}; set --interface/--channel, CAN_INTERFACE/"
                        "CAN_CHANNEL or ~/.canrc") from error


def _interface_configured(context: str | None) -> bool:
    """Whether python-can's configuration chain (``can.rc``, ``CAN_*`` environment, config files)
    names an interface; when unsure, True (python-can then says what is wrong)."""
    try:
        sources = [can.rc, can.util.load_environment_config(context), can.util.load_environment_config(),
                   can.util.load_file_config(None, context) if context else {}, can.util.load_file_config()]
    except Exception:  # noqa: BLE001 - e.g. CAN_CONFIG not JSON: python-can reports it
        return True
    return any(source.get("interface") or source.get("bustype") for source in sources)


def _reason(error: BaseException) -> str:
    if isinstance(error, FileNotFoundError) or getattr(error, "errno", None) == errno.ENOENT:
        return f"device not found ({error})"
    if isinstance(error, OSError) and error.errno == errno.EAFNOSUPPORT:
        return f"SocketCAN is not supported by this kernel ({error})"
    if isinstance(error, OSError) and error.errno == errno.ENODEV:
        return f"no such network interface ({error})"
    return f"{type(error).__name__}: {error}"


def vcan_available(name: str = "vcan0") -> bool:
    """True if the SocketCAN interface ``name`` exists and a raw CAN socket can bind to it."""
    try:
        if not Path("/sys/class/net", name).exists():
            return False
        with socket.socket(socket.AF_CAN, socket.SOCK_RAW, socket.CAN_RAW) as sock:
            sock.bind((name,))
        return True
    except Exception:  # noqa: BLE001 - detection never raises
        return False


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
    starts sending.  The bridge notices that an end was opened or closed within ``poll_interval``
    seconds (or at once, when bytes arrive for it), so bytes written less than that before the
    receiver opened may still arrive.
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
        for fd in (self._master_a, self._master_b, self._wake_read, self._wake_write):
            try:
                os.close(fd)
            except OSError:
                pass
        if self.dropped_bytes:
            log.warning("PtyPair dropped %d bytes (peer not reading)", self.dropped_bytes)
