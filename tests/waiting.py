"""Bounded waiting for tests that cross processes or network sessions (never a speed assertion)."""

from __future__ import annotations

import time


def wait_until(predicate, timeout: float, poll_s: float = 0.05) -> bool:
    """Poll ``predicate`` until it holds or ``timeout`` seconds pass; its final value."""
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if predicate():
            return True
        time.sleep(poll_s)
    return bool(predicate())
