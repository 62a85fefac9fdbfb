"""Atomic JSON persistence of the agent state (no pickle).

The state file is written to a temporary file in the same directory, flushed and fsynced, then
renamed over the old one, so a crash leaves either the old or the new state, never a torn file.
NaN and infinities are stored as ``null`` (strict JSON).
"""

from __future__ import annotations

import json
import logging
import os
import tempfile
from pathlib import Path
from typing import Any

from edge_monitor.errors import StateError
from edge_monitor.records import to_json

log = logging.getLogger(__name__)

STATE_FILE = "agent_state.json"
STATE_VERSION = 1


class StateStore:
    """Reads and atomically writes ``<state_dir>/agent_state.json``."""

    def __init__(self, state_dir: str | os.PathLike) -> None:
        self.dir = Path(state_dir)
        try:
            self.dir.mkdir(parents=True, exist_ok=True)
        except OSError as exc:
            raise StateError(f"state directory {self.dir}: cannot create it ({exc.strerror}); "
                             f"pass a writable --state-dir") from None
        if not os.access(self.dir, os.W_OK):
            raise StateError(f"state directory {self.dir} is not writable; pass a writable --state-dir")
        self.path = self.dir / STATE_FILE

    def load(self) -> dict[str, Any] | None:
        if not self.path.exists():
            return None
        try:
            state = json.loads(self.path.read_text(encoding="utf-8"))
        except (OSError, json.JSONDecodeError) as exc:
            raise StateError(f"state file {self.path} is unreadable ({exc}); move it away to start "
                             f"learning afresh") from None
        if state.get("version") != STATE_VERSION:
            raise StateError(f"state file {self.path} has version {state.get('version')!r}, expected "
                             f"{STATE_VERSION}; move it away to start learning afresh")
        return state

    def save(self, state: dict[str, Any]) -> None:
        payload = to_json({"version": STATE_VERSION, **state})
        fd, tmp = tempfile.mkstemp(prefix=".agent_state.", suffix=".tmp", dir=self.dir)
        try:
            with os.fdopen(fd, "w", encoding="utf-8") as fh:
                fh.write(payload)
                fh.flush()
                os.fsync(fh.fileno())
            os.replace(tmp, self.path)
        except BaseException:
            try:
                os.unlink(tmp)
            except OSError:
                pass
            raise
