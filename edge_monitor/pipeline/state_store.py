"""Atomic JSON persistence of the agent state (no pickle).

The state file is written to a temporary file in the same directory, flushed and fsynced, then
renamed over the old one, so a crash leaves either the old or the new state, never a torn file. A
save that fails (a full disk: ENOSPC) removes its temporary file, keeps the previous state file,
is counted (``save_errors``) and raises :class:`StateSaveError`. NaN and infinities are stored as
``null`` (strict JSON).

A command's agent claims the directory (:meth:`StateStore.claim`): one agent per state directory.
Reading treats the file as hostile: only a regular file is read (a FIFO, a device or a symlink to
one is moved aside unread), at most :data:`MAX_STATE_BYTES`, and integers of more than
:data:`MAX_INT_DIGITS` digits are refused before Python converts them.
"""

from __future__ import annotations

import errno
import json
import logging
import os
import tempfile
import time
from pathlib import Path
from typing import Any

from edge_monitor.errors import StateError
from edge_monitor.records import to_json
from protocol.files import file_kind, read_regular

log = logging.getLogger(__name__)

STATE_FILE = "agent_state.json"
LOCK_FILE = "agent_state.lock"
STATE_VERSION = 1
#: Largest state file read [bytes]. A 6-joint state is ≈ 0.1 MB; the largest the validation bounds
#: allow (8 joints, 65 536-point KDE grids, 10 000-cycle GLR windows) is ≈ 40 MB.
MAX_STATE_BYTES = 64 << 20
#: Longest integer literal accepted (the validation bounds numbers to ±10¹⁵ anyway).
MAX_INT_DIGITS = 32


class StateSaveError(OSError):
    """The state could not be written (e.g. the disk is full); the previous state file is kept."""


def _bounded_int(text: str) -> int:
    if len(text.lstrip("-")) > MAX_INT_DIGITS:
        raise ValueError(f"an integer of {len(text)} digits")
    return int(text)


class StateStore:
    """Reads and atomically writes ``<state_dir>/agent_state.json``."""

    def __init__(self, state_dir: str | os.PathLike) -> None:
        self.dir = Path(state_dir)
        try:
            self.dir.mkdir(exist_ok=True)      # its parent must exist: a typo must not make a directory tree
        except FileNotFoundError:
            raise StateError(f"state directory {self.dir}: its folder {self.dir.parent} does not exist; create it "
                             "or pass another --state-dir") from None
        except FileExistsError:         # a file, a device, a dangling symlink or a loop of them
            try:
                what = file_kind(os.stat(self.dir).st_mode)
            except OSError as exc:
                what = "a symlink loop" if exc.errno == errno.ELOOP else "a symlink to nothing"
            raise StateError(f"state directory {self.dir} is {what}, not a directory; pass a directory (or a path "
                             "to create one in) as --state-dir") from None
        except OSError as exc:
            raise StateError(f"state directory {self.dir}: cannot create it ({exc.strerror}); "
                             f"pass a writable --state-dir") from None
        if not os.access(self.dir, os.W_OK):
            raise StateError(f"state directory {self.dir} is not writable; pass a writable --state-dir")
        self.path = self.dir / STATE_FILE
        if self.path.exists() and not os.access(self.path, os.R_OK | os.W_OK):
            raise StateError(f"state file {self.path} is not readable and writable by this user; fix its "
                             f"permissions (the learned models in it are kept) or pass another --state-dir")
        self._lock_fd: int | None = None
        self.rejected = 0         # state files moved aside as unusable
        self.save_errors = 0      # saves that failed (the previous state file was kept)
        self.last_save_error: str | None = None     # why the latest save failed; None once one succeeds

    def claim(self) -> None:
        """Hold the state directory for this process (an exclusive ``flock`` on ``agent_state.lock``, released
        when the process ends, also by kill -9): a second agent on the same directory would overwrite the
        first one's learned state, so it gets :class:`StateError` naming the holder instead."""
        import fcntl
        path = self.dir / LOCK_FILE
        try:
            fd = os.open(path, os.O_RDWR | os.O_CREAT | os.O_NOFOLLOW | os.O_CLOEXEC, 0o644)
        except OSError as exc:
            raise StateError(f"state directory {self.dir}: cannot open {LOCK_FILE} ({exc.strerror}); pass a "
                             "writable --state-dir") from None
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except OSError:
            holder = os.pread(fd, 64, 0).decode("ascii", "replace").strip() or "unknown"
            os.close(fd)
            raise StateError(f"state directory {self.dir} is in use by another agent (pid {holder}): two agents "
                             "on one --state-dir would overwrite each other's learned state; stop the other one or "
                             "give each its own --state-dir") from None
        try:                    # who holds it, for the message of the next one (a full disk: the lock still holds)
            os.ftruncate(fd, 0)
            os.pwrite(fd, f"{os.getpid()}\n".encode(), 0)
        except OSError:
            pass
        self._lock_fd = fd
        self._remove_leftovers()

    def _remove_leftovers(self) -> None:
        """Temporary files of saves a kill -9 cut (``.agent_state.*.tmp``, ``.replayed_input.json.*.partial``): only
        the holder of the lock writes them, so with it held every one left is garbage (up to a state's size each)."""
        for pattern in (".agent_state.*.tmp", ".replayed_input.json.*.partial"):
            for leftover in self.dir.glob(pattern):
                try:
                    if leftover.is_file() and not leftover.is_symlink():
                        leftover.unlink()
                        log.info("removed %s, left by a save that was cut short", leftover)
                except OSError:
                    pass

    def load(self) -> dict[str, Any] | None:
        """The saved state, or None when there is none or it is unusable (then it is moved aside by
        :meth:`reject`, and the agent relearns)."""
        if not os.path.lexists(self.path):
            return None
        try:
            text = read_regular(self.path, MAX_STATE_BYTES).decode("utf-8")
            state = json.loads(text, parse_int=_bounded_int)
        except (OSError, ValueError, RecursionError) as exc:      # UnicodeDecodeError, JSONDecodeError: ValueError
            self.reject(f"unreadable ({exc})")
            return None
        version = state.get("version") if isinstance(state, dict) else None
        if version != STATE_VERSION:
            self.reject(f"version {version!r}, expected {STATE_VERSION}")
            return None
        return state

    def reject(self, reason: str) -> Path | None:
        """Move an unusable state file aside (``agent_state.json.rejected-<UTC time, ns>``) with a warning;
        the agent then starts learning afresh. Returns where it went (None if it could not move)."""
        now_ns = time.time_ns()        # one reading: the seconds and the nanoseconds of the same instant
        stamp = time.strftime("%Y%m%dT%H%M%S", time.gmtime(now_ns // 10**9)) + f".{now_ns % 10**9:09d}Z"
        aside = self.path.with_name(f"{STATE_FILE}.rejected-{stamp}")
        try:
            os.replace(self.path, aside)
        except OSError as exc:
            raise StateError(f"state file {self.path} is unusable ({reason}) and cannot be moved aside "
                             f"({exc.strerror}); move it away to start learning afresh") from None
        self.rejected += 1
        log.warning("state file %s is unusable: %s; moved it to %s, learning afresh", self.path, reason, aside.name)
        return aside

    def save(self, state: dict[str, Any]) -> None:
        """Write ``state`` atomically; :class:`StateSaveError` (the previous file kept) if it cannot."""
        payload = to_json({"version": STATE_VERSION, **state}).encode("utf-8")
        tmp: str | None = None
        try:
            fd, tmp = tempfile.mkstemp(prefix=".agent_state.", suffix=".tmp", dir=self.dir)
            with os.fdopen(fd, "wb") as fh:
                fh.write(payload)
                fh.flush()
                os.fsync(fh.fileno())
            os.replace(tmp, self.path)
            tmp = None
        except OSError as exc:
            self.save_errors += 1
            self.last_save_error = f"{exc.strerror or exc}"
            error = StateSaveError(f"state not saved to {self.path}: {exc.strerror or exc}; "
                                   "the previous state file is kept")
            error.errno = exc.errno
            raise error from None
        finally:
            if tmp is not None:
                try:
                    os.unlink(tmp)
                except OSError:
                    pass
        self.last_save_error = None
