"""JSON Lines output: one symptom record per line (and alarm records, marked by ``"kind"``)."""

from __future__ import annotations

import logging
from pathlib import Path
from typing import Any, TextIO

from edge_monitor.records import Alarm, Health, Symptom, to_json

log = logging.getLogger(__name__)


class JsonlSink:
    """Appends symptom records to a ``.jsonl`` file (``-`` for standard output); never raises."""

    def __init__(self, path: str | Path, include_alarms: bool = False) -> None:
        self.path = str(path)
        self.include_alarms = include_alarms
        self.written = 0
        self.failed = 0
        self._fh: TextIO | None = None
        try:
            if self.path == "-":
                import sys
                self._fh = sys.stdout
            else:
                Path(self.path).parent.mkdir(parents=True, exist_ok=True)
                self._fh = open(self.path, "a", encoding="utf-8")
        except OSError as exc:
            log.error("JSONL output %s cannot be opened (%s); symptoms will be counted as undelivered",
                      self.path, exc.strerror)

    def _write(self, record: dict[str, Any]) -> None:
        if self._fh is None:
            self.failed += 1
            return
        try:
            self._fh.write(to_json(record) + "\n")
            self.written += 1
        except (OSError, ValueError) as exc:
            self.failed += 1
            log.error("JSONL output %s: write failed (%s)", self.path, exc)

    def on_symptom(self, symptom: Symptom) -> None:
        self._write(symptom.to_dict())

    def on_alarm(self, alarm: Alarm) -> None:
        if self.include_alarms:
            self._write({"kind": "alarm", **alarm.to_dict()})

    def on_health(self, health: Health) -> None:
        """Health is not written to the symptom file."""

    def close(self) -> None:
        if self._fh is not None and self.path != "-":
            self._fh.close()
        elif self._fh is not None:
            self._fh.flush()
        self._fh = None
