"""JSON Lines output: one symptom record per line (and alarm records, marked by ``"kind"``).

Crash-safe: every record is flushed and fsynced before the agent saves the state that says it was
emitted, so a kill -9 loses nothing the state counts as published. What a kill can leave is a torn
last line (cut mid-write; removed and counted when the file is opened again) and records written
after the last state save, which the restarted agent emits again: those exact duplicates (same
robot, joint and cycle as a record in the file's tail) are skipped and counted, so the file holds
every cycle once. Only exact matches are skipped: a controller that restarts its cycle numbers
still gets every record written. ``recent`` holds the symptom records of the file's tail, e.g. for
the Zenoh publisher to send again after a restart (``edge_monitor.app``).
"""

from __future__ import annotations

import json
import logging
import os
from pathlib import Path
from typing import Any, TextIO

from edge_monitor.records import Advisory, Alarm, Health, Symptom, to_json

log = logging.getLogger(__name__)


#: How much of an existing file's end is read for the records a restart may repeat [bytes].
TAIL_BYTES = 1 << 20


class JsonlSink:
    """Appends symptom records to a ``.jsonl`` file (``-`` for standard output); never raises."""

    def __init__(self, path: str | Path, include_alarms: bool = False, durable: bool = True) -> None:
        self.path = str(path)
        self.include_alarms = include_alarms
        self.durable = durable and self.path != "-"
        self.written = 0
        self.failed = 0
        self.duplicates_skipped = 0
        self.torn_bytes_removed = 0
        self.recent: list[dict[str, Any]] = []        # symptom records of the tail found at opening
        self._seen: set[tuple[Any, Any, Any]] = set()
        self._fh: TextIO | None = None
        try:
            if self.path == "-":
                import sys
                self._fh = sys.stdout
            else:
                Path(self.path).parent.mkdir(parents=True, exist_ok=True)
                self._seen = self._recover(Path(self.path))
                self._fh = open(self.path, "a", encoding="utf-8")
        except OSError as exc:
            log.error("JSONL output %s cannot be opened (%s); symptoms will be counted as undelivered",
                      self.path, exc.strerror)

    def _recover(self, path: Path) -> set[tuple[Any, Any, Any]]:
        """Cut a torn last line; the (robot, joint, cycle) of the symptoms in the file's tail."""
        if not path.exists():
            return set()
        with open(path, "rb+") as fh:
            size = fh.seek(0, os.SEEK_END)
            fh.seek(max(0, size - TAIL_BYTES))
            tail = fh.read()
            end = tail.rfind(b"\n") + 1                    # 0 when the tail holds no complete line
            if end < len(tail) and (size <= TAIL_BYTES or end > 0):
                self.torn_bytes_removed = len(tail) - end
                fh.truncate(size - self.torn_bytes_removed)
                log.warning("JSONL output %s ended in a torn line (%d bytes, a crash mid-write): removed",
                            path, self.torn_bytes_removed)
        seen = set()
        for line in tail[:end].splitlines():
            try:
                record = json.loads(line)
            except ValueError:
                continue                                    # the first, partial line of the tail window
            if isinstance(record, dict) and "kind" not in record:
                seen.add((record.get("robot"), record.get("joint"), record.get("cycle")))
                self.recent.append(record)
        return seen

    def _write(self, record: dict[str, Any]) -> None:
        if self._fh is None:
            self.failed += 1
            return
        try:
            self._fh.write(to_json(record) + "\n")
            if self.durable:
                self._fh.flush()
                os.fsync(self._fh.fileno())
            self.written += 1
        except (OSError, ValueError) as exc:
            self.failed += 1
            log.error("JSONL output %s: write failed (%s)", self.path, exc)

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

    def close(self) -> None:
        if self._fh is not None and self.path != "-":
            self._fh.close()
        elif self._fh is not None:
            self._fh.flush()
        self._fh = None
