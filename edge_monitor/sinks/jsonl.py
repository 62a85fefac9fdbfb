"""JSON Lines output: one symptom record per line (and alarm records, marked by ``"kind"``).

Crash-safe: every record is written whole, and fsynced before the agent saves the state that says it
was emitted (the agent calls :meth:`JsonlSink.sync` before every state save), so neither a kill -9 nor a
power cut loses anything the state counts as published. Between state saves the records are fsynced
in groups, at most :data:`SYNC_INTERVAL_S` after they were written (one fsync per record cost a replay
≈ 8 ms a record on this project's test machine), and at close. What a kill can leave
is a torn last line (cut mid-write; removed, whatever its length, and counted when the file is opened
again) and records written after the last state save, which the restarted agent emits again: those
exact duplicates (same robot, joint and cycle as a record in the file's tail) are skipped and
counted, so the file holds every cycle once. Only exact matches are skipped: a controller that
restarts its cycle numbers still gets every record written. ``recent`` holds the symptom records of
the file's tail, e.g. for the Zenoh publisher to send again after a restart (``edge_monitor.app``).

A full disk (ENOSPC) or another write error does not stop the agent: the partly written line is cut
off again (the file keeps its last good version), the record is counted in ``failures`` (the agent's
``sink_errors``) and the next record is tried. Only a regular file is written: a directory, a device
(``/dev/full``, ``/dev/zero``), a FIFO or a socket is refused when the sink opens
(:class:`JsonlOpenError`), and so is an existing file that is not JSON Lines (it does not begin with
``{``). Lines of the tail are untrusted: one that is not a usable symptom record is counted
(``unusable_tail_lines``) and ignored.

Rotation (``Rotation``): before a record would take the file past ``max_bytes`` it is renamed to
``PATH.1`` (``PATH.1`` to ``PATH.2``, …, keeping ``keep`` of them) and a new ``PATH`` is begun; records
are never split across files. For logrotate, :meth:`JsonlSink.request_reopen` (the agent's SIGHUP)
makes the sink close and reopen ``PATH`` before its next record.
"""

from __future__ import annotations

import errno
import json
import logging
import os
import sys
import threading
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable

from edge_monitor.errors import ConfigError
from edge_monitor.records import Advisory, Alarm, Health, Symptom, to_json
from protocol.files import NotARegularFile, open_regular

log = logging.getLogger(__name__)


#: How much of an existing file's end is read for the records a restart may repeat [bytes].
TAIL_BYTES = 1 << 20
#: Chunk of the backward search for the last line end of a torn file [bytes].
SCAN_BYTES = 1 << 16
#: Smallest rotation size [bytes] (a symptom record is a few kB).
MIN_ROTATE_BYTES = 1 << 16
MAX_ROTATE_BYTES = 1 << 40
MAX_KEEP = 1000
_OPEN_FLAGS = os.O_RDWR | os.O_CREAT | os.O_APPEND
#: Longest time a written record waits for its fsync when no state save asks for one first [s].
SYNC_INTERVAL_S = 1.0


class JsonlOpenError(OSError):
    """The JSONL output cannot be used: not a regular file, not JSON Lines, or not writable."""

    def __init__(self, message: str, errno: int | None = None) -> None:
        super().__init__(message)
        self.errno = errno


@dataclass(frozen=True)
class Rotation:
    """Size-based rotation: at most ``max_bytes`` per file (0: never rotate), ``keep`` old files."""

    max_bytes: int = 0
    keep: int = 5

    def __post_init__(self) -> None:
        ok = isinstance(self.max_bytes, int) and (self.max_bytes == 0
                                                 or MIN_ROTATE_BYTES <= self.max_bytes <= MAX_ROTATE_BYTES)
        if not ok:
            raise ConfigError(f"jsonl_max_bytes: must be 0 (no rotation) or {MIN_ROTATE_BYTES} … "
                              f"{MAX_ROTATE_BYTES} bytes, got {self.max_bytes!r}")
        if not (isinstance(self.keep, int) and 1 <= self.keep <= MAX_KEEP):
            raise ConfigError(f"jsonl_keep: must be 1 … {MAX_KEEP} rotated files, got {self.keep!r}")


def rotated_path(path: str | Path, index: int) -> Path:
    """``PATH.index``: where rotation puts the ``index``-th older file."""
    return Path(f"{path}.{index}")


def _usable_key(record: Any) -> tuple[str, int, int] | None:
    """(robot, joint, cycle) of a symptom record read back from the file, or None if it is none."""
    if not isinstance(record, dict) or "kind" in record:
        return None
    robot, joint, cycle = record.get("robot"), record.get("joint"), record.get("cycle")
    if (not isinstance(robot, str) or not isinstance(joint, int) or not isinstance(cycle, int)
            or isinstance(joint, bool) or isinstance(cycle, bool)):
        return None
    return robot, joint, cycle


class JsonlSink:
    """Appends symptom records to a ``.jsonl`` file (``-`` for standard output); never raises once open.

    ``strict``: a file that cannot be opened raises :class:`JsonlOpenError` (the agent's commands
    exit 1); otherwise it is logged and every record is counted as a failure.
    """

    def __init__(self, path: str | Path, include_alarms: bool = False, durable: bool = True,
                 rotation: Rotation = Rotation(), strict: bool = False, sync_interval_s: float = SYNC_INTERVAL_S,
                 clock: Callable[[], float] = time.monotonic) -> None:
        self.path = str(path)
        self.sync_interval_s, self._clock = float(sync_interval_s), clock
        self.fsyncs = 0
        self._unsynced = 0                # records written since the last fsync
        self._synced_at = clock()
        self.include_alarms = include_alarms
        self.durable = durable and self.path != "-"
        self.rotation = rotation
        self.written = 0
        self.failures = 0                # records not written (the agent counts them as sink_errors)
        self.duplicates_skipped = 0
        self.torn_bytes_removed = 0
        self.unusable_tail_lines = 0     # lines of the tail that are no usable symptom record
        self.rotations = 0
        self.reopens = 0
        self.recent: list[dict[str, Any]] = []        # symptom records of the tail found at opening
        self._seen: set[tuple[str, int, int]] = set()
        self._fd: int | None = None
        self._opened = False              # opened (and its tail checked) once
        self._reopen_requested = False    # set from a signal handler: a plain flag, no lock
        self._lock = threading.Lock()
        if self.path == "-":
            return
        try:
            self._fd = self._open(recover=True)
            self._opened = True
        except OSError as exc:
            message = f"JSONL output {self.path}: {exc.strerror or exc}"
            if strict:
                raise JsonlOpenError(message, exc.errno) from None
            log.error("%s; symptoms will be counted as undelivered", message)

    # ------------------------------------------------------------------ opening
    def _open(self, recover: bool) -> int:
        """Open (create) the file for appending; on the first opening repair a torn tail and read the tail."""
        parent = Path(self.path).parent
        if not parent.is_dir():         # a typo in the path must not make a directory tree
            raise JsonlOpenError(f"its folder {parent} does not exist; create it (mkdir -p) or fix the path",
                                 errno.ENOENT)
        try:
            fd = open_regular(self.path, _OPEN_FLAGS)
        except NotARegularFile as exc:
            raise JsonlOpenError(f"{exc.reason}; give a file path (or - for standard output)") from None
        try:
            if recover:
                self._recover(fd, os.fstat(fd).st_size)
        except BaseException:
            os.close(fd)
            raise
        return fd

    def _recover(self, fd: int, size: int) -> None:
        """Cut a torn last line (any length); read the symptoms of the file's tail (and of ``PATH.1``
        when the current file holds less than :data:`TAIL_BYTES`, as after a rotation)."""
        if size and os.pread(fd, 1, 0) != b"{":
            raise JsonlOpenError("exists and is not a JSON Lines file (it does not begin with '{'); "
                                    "give a new path or move the file away")
        end = _last_line_end(fd, size)
        if end < size:
            os.ftruncate(fd, end)
            self.torn_bytes_removed = size - end
            log.warning("JSONL output %s ended in a torn line (%d bytes, a crash mid-write): removed",
                        self.path, self.torn_bytes_removed)
        tail = os.pread(fd, min(end, TAIL_BYTES), end - min(end, TAIL_BYTES))
        older = self._older_tail(TAIL_BYTES - len(tail)) if len(tail) < TAIL_BYTES else b""
        complete = older + tail if end <= TAIL_BYTES else tail
        first_whole = 0 if end <= TAIL_BYTES and not older else complete.find(b"\n") + 1
        for line in complete[first_whole:].splitlines():
            try:
                record = json.loads(line)
            except (ValueError, RecursionError):
                record = None
            key = _usable_key(record)
            if key is None:
                self.unusable_tail_lines += 1
                continue
            self._seen.add(key)
            self.recent.append(record)
        if self.unusable_tail_lines:
            log.warning("JSONL output %s: %d line(s) of its tail are no symptom record of this agent; ignored",
                        self.path, self.unusable_tail_lines)

    def _older_tail(self, budget: int) -> bytes:
        """The last ``budget`` bytes of ``PATH.1`` if it is a regular file (else nothing)."""
        try:
            fd = open_regular(rotated_path(self.path, 1))
        except (OSError, NotARegularFile):
            return b""
        try:
            end = _last_line_end(fd, os.fstat(fd).st_size)
            return os.pread(fd, min(end, budget), end - min(end, budget))
        finally:
            os.close(fd)

    def request_reopen(self) -> None:
        """Close and reopen ``PATH`` before the next record (logrotate's SIGHUP). Signal-safe."""
        self._reopen_requested = True

    # ------------------------------------------------------------------ writing
    def _write(self, record: dict[str, Any]) -> None:
        line = (to_json(record) + "\n").encode("utf-8")
        if self.path == "-":
            self._write_stdout(line)
            return
        with self._lock:
            if self._reopen_requested:
                self._reopen_requested = False
                self._reopen_file()
            elif self._fd is not None and self._path_lost():
                log.warning("JSONL output %s was deleted or replaced while open; writing on in a new %s (records "
                            "would otherwise go to a file no one can read)", self.path, self.path)
                self._reopen_file()
            if self._fd is None and not self._retry_open():
                self.failures += 1
                return
            if self.rotation.max_bytes:
                self._rotate_if_full(len(line))
            self._append(line)

    def _path_lost(self) -> bool:
        """PATH no longer names the open file: deleted, or renamed (logrotate without the SIGHUP)."""
        try:
            ours, now = os.fstat(self._fd), os.stat(self.path)     # type: ignore[arg-type]
        except FileNotFoundError:
            return True
        except OSError:
            return False
        return (ours.st_dev, ours.st_ino) != (now.st_dev, now.st_ino)

    def _append(self, line: bytes) -> None:
        """Write one whole line; on failure cut back to the file's size before it (its last good version)."""
        fd = self._fd
        if fd is None:
            self.failures += 1
            return
        start = -1
        try:
            start = os.fstat(fd).st_size
            view = memoryview(line)
            while view:
                view = view[os.write(fd, view):]
            self.written += 1
        except OSError as exc:
            self.failures += 1
            if start >= 0:
                try:
                    os.ftruncate(fd, start)
                except OSError:
                    pass
            if self.failures in (1, 10, 100) or self.failures % 1000 == 0:
                log.error("JSONL output %s: record not written (%s; failure #%d, logged at 1, 10, 100, every "
                          "1000; the file keeps its last complete record)", self.path, exc.strerror or exc,
                          self.failures)
        else:
            if self.durable:
                self._unsynced += 1
                if self._clock() - self._synced_at >= self.sync_interval_s:
                    self._sync_fd()

    def sync(self) -> None:
        """fsync the records written since the last fsync (the agent calls it before saving its state)."""
        if self.path != "-":
            with self._lock:
                self._sync_fd()

    def _sync_fd(self) -> None:
        """fsync if records wait for it; a failure is logged and counted (``failures``), the records stay
        in the file (written, perhaps not yet on disk)."""
        self._synced_at = self._clock()
        if not self._unsynced or self._fd is None:
            return
        waiting, self._unsynced = self._unsynced, 0
        try:
            os.fsync(self._fd)
            self.fsyncs += 1
        except OSError as exc:
            self.failures += 1
            log.error("JSONL output %s: fsync failed (%s); the last %d record(s) may not be on disk",
                      self.path, exc.strerror or exc, waiting)

    def _write_stdout(self, line: bytes) -> None:
        try:
            sys.stdout.write(line.decode("utf-8"))
            sys.stdout.flush()
            self.written += 1
        except (OSError, ValueError) as exc:
            self.failures += 1
            log.error("JSONL output to standard output failed (%s)", exc)

    def _retry_open(self) -> bool:
        """Open the path again (after a failure, a rotation or a reopen); checked as at first if it never opened."""
        try:
            self._fd = self._open(recover=not self._opened)
        except OSError:
            return False
        self._opened = True
        return True

    def _reopen_file(self) -> None:
        self._close_fd()
        self.reopens += 1
        if self._retry_open():
            log.info("JSONL output %s reopened", self.path)
        else:
            log.error("JSONL output %s: cannot reopen it; records are counted as undelivered until it can",
                      self.path)

    def _rotate_if_full(self, incoming: int) -> None:
        """Rename ``PATH`` → ``PATH.1`` (shifting older ones, dropping the oldest) before a record that
        would take it past ``max_bytes``; a record is never split between files."""
        fd = self._fd
        if fd is None:
            return
        try:
            size = os.fstat(fd).st_size
            if size == 0 or size + incoming <= self.rotation.max_bytes:
                return
            keep = self.rotation.keep
            for index in range(keep, 0, -1):
                older = rotated_path(self.path, index)
                if index == keep:
                    older.unlink(missing_ok=True)
                elif older.exists():
                    os.replace(older, rotated_path(self.path, index + 1))
            os.replace(self.path, rotated_path(self.path, 1))
        except OSError as exc:
            log.error("JSONL output %s: rotation failed (%s); writing on in the current file", self.path,
                      exc.strerror or exc)
            return
        self._close_fd()
        self.rotations += 1
        self._retry_open()
        _sync_directory(Path(self.path).parent)

    def _close_fd(self) -> None:
        self._sync_fd()
        if self._fd is not None:
            try:
                os.close(self._fd)
            except OSError:
                pass
            self._fd = None

    # ------------------------------------------------------------------ sink interface
    def on_symptom(self, symptom: Symptom) -> None:
        key = (symptom.robot, symptom.joint, symptom.cycle)
        if key in self._seen:                # emitted before a crash, again after the restart
            self._seen.discard(key)
            self.duplicates_skipped += 1
            return
        self._write(symptom.to_dict())

    def on_alarm(self, alarm: Alarm) -> None:
        if self.include_alarms:
            self._write({"kind": "alarm", **alarm.to_dict()})

    def on_advisory(self, advisory: Advisory) -> None:
        if self.include_alarms:
            self._write({"kind": "advisory", **advisory.to_dict()})

    def on_health(self, health: Health) -> None:
        """Health is not written to the symptom file."""

    def counters(self) -> dict[str, int]:
        """What the sink did, for health records."""
        return {"jsonl_written": self.written, "jsonl_failures": self.failures,
                "jsonl_rotations": self.rotations, "jsonl_reopens": self.reopens}

    def close(self) -> None:
        if self.path == "-":
            try:
                sys.stdout.flush()
            except (OSError, ValueError):
                pass
            return
        with self._lock:
            self._close_fd()


def _last_line_end(fd: int, size: int) -> int:
    """Offset just past the last ``\\n`` of the file (0 if none), searching backward in chunks:
    memory bounded whatever the length of a torn last line."""
    end = size
    while end > 0:
        start = max(0, end - SCAN_BYTES)
        chunk = os.pread(fd, end - start, start)
        found = chunk.rfind(b"\n")
        if found >= 0:
            return start + found + 1
        end = start
    return 0


def _sync_directory(folder: Path) -> None:
    """fsync a directory so renames in it survive a power cut (best effort)."""
    try:
        fd = os.open(folder, os.O_RDONLY | getattr(os, "O_DIRECTORY", 0))
    except OSError:
        return
    try:
        os.fsync(fd)
    except OSError:
        pass
    finally:
        os.close(fd)
