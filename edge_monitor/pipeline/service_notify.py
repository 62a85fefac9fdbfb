"""The systemd notification protocol, without a dependency: ``READY=1`` once the agent runs, ``WATCHDOG=1``
while data flows (``WatchdogSec`` in the unit: no ping for that long and systemd restarts the agent),
``STATUS=…`` for ``systemctl status``, ``STOPPING=1`` at the end (docs/OPERATIONS.md).

Datagrams go to the socket systemd names in ``NOTIFY_SOCKET`` (a path, or ``@name`` in the abstract
namespace); without it (not under systemd, ``Type=exec``) every call does nothing. ``WATCHDOG_USEC``
(set by systemd with ``WatchdogSec``) sets how often to ping: twice per period. A failed send is logged
once and counted, never raised.
"""

from __future__ import annotations

import logging
import os
import socket

log = logging.getLogger(__name__)


class ServiceNotifier:
    """Sends sd_notify messages when ``NOTIFY_SOCKET`` is set (see the module docstring)."""

    def __init__(self, environ: dict[str, str] | None = None) -> None:
        env = os.environ if environ is None else environ
        address = env.get("NOTIFY_SOCKET", "")
        self.address = ("\0" + address[1:]) if address.startswith("@") else address
        usec = env.get("WATCHDOG_USEC", "")
        pid = env.get("WATCHDOG_PID", "")
        mine = not pid or pid == str(os.getpid())
        self.watchdog_s = int(usec) / 1e6 if usec.isdigit() and int(usec) > 0 and mine else None
        self.errors = 0
        self._last_ping: float | None = None

    @property
    def enabled(self) -> bool:
        return bool(self.address)

    def send(self, message: str) -> bool:
        if not self.address:
            return False
        try:
            with socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM | socket.SOCK_CLOEXEC) as sock:
                sock.sendto(message.encode(), self.address)
            return True
        except OSError as exc:
            self.errors += 1
            if self.errors == 1:
                log.warning("cannot notify systemd at %s (%s); the watchdog may restart the agent",
                            self.address.lstrip("\0"), exc.strerror or exc)
            return False

    def ready(self, status: str) -> None:
        self.send(f"READY=1\nSTATUS={status}")

    def watchdog(self, now: float, flowing: bool, status: str) -> None:
        """Ping the watchdog (at most twice per ``WatchdogSec``) while ``flowing``; else say why not."""
        if self.watchdog_s is None:
            return
        if not flowing:
            if self._last_ping is not None:
                self.send(f"STATUS={status}")
                self._last_ping = None
            return
        if self._last_ping is None or now - self._last_ping >= self.watchdog_s / 2:
            self.send(f"WATCHDOG=1\nSTATUS={status}")
            self._last_ping = now

    def stopping(self) -> None:
        self.send("STOPPING=1")
