"""Loopback networking helpers: every server of this project binds 127.0.0.1."""

from __future__ import annotations

import socket

#: The largest TCP/UDP port number.
MAX_PORT = 65535


def is_port(port: int) -> bool:
    """Whether ``port`` is a TCP/UDP port number (0: the kernel picks a free one)."""
    return 0 <= port <= MAX_PORT


def free_loopback_port(preferred: int = 0) -> int:
    """A TCP port free on 127.0.0.1: ``preferred`` if it can be bound, else one the kernel picks."""
    with socket.socket() as probe:
        try:
            probe.bind(("127.0.0.1", preferred))
        except OSError:
            probe.bind(("127.0.0.1", 0))
        return probe.getsockname()[1]
