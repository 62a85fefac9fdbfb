"""``edge-monitor historian import PATH…``: an agent's JSONL files into the history, idempotently.

A line without ``kind`` is a symptom record (its friction curve is stored as the friction record too);
``"kind": "alarm"`` and ``"kind": "advisory"`` lines are those records (stored without the ``kind``
field, as published). The robot is the record's own. Every record goes through the same identity as a
live one, so importing a file twice, or a file whose records the historian already received over
Zenoh, stores nothing twice. Files are read as untrusted input: regular files only, lines of at most
1 MiB, each bad line counted with its number (the first few are named), never a traceback. After the
import the gaps that remain for the imported robots are reported.
"""

from __future__ import annotations

import json
import logging
import os
import time
from collections import Counter
from dataclasses import dataclass, field
from typing import Any, BinaryIO, Iterator

from edge_monitor.historian.database import Connection
from edge_monitor.historian.identity import MAX_RECORD_BYTES, Rejection, Row, friction_of, row_of
from edge_monitor.historian.writes import insert_rows
from edge_monitor.sinks.keys import ADVISORY, ALARM, SYMPTOM
from protocol.files import NotARegularFile, open_regular

log = logging.getLogger(__name__)

BATCH = 1000
EXAMPLES = 5


@dataclass
class ImportReport:
    """What an import did, over all its files."""

    files: int = 0
    lines: int = 0
    stored: int = 0
    duplicates: int = 0
    friction_present: int = 0
    expired: int = 0
    bad_lines: Counter = field(default_factory=Counter)
    examples: list[str] = field(default_factory=list)
    robots: set[str] = field(default_factory=set)
    span: tuple[float, float] | None = None
    unreadable: list[str] = field(default_factory=list)

    def bad(self, where: str, reason: str) -> None:
        self.bad_lines[reason] += 1
        if len(self.examples) < EXAMPLES:
            self.examples.append(f"{where}: {reason}")

    def to_dict(self) -> dict[str, Any]:
        return {"files": self.files, "lines": self.lines, "stored": self.stored, "duplicates": self.duplicates,
                "friction_present": self.friction_present, "expired": self.expired,
                "bad_lines": dict(self.bad_lines), "bad_line_examples": self.examples,
                "robots": sorted(self.robots), "unreadable": self.unreadable}


def _lines(stream: BinaryIO) -> Iterator[bytes | None]:
    """The file's lines; ``None`` for a line longer than :data:`MAX_RECORD_BYTES` (skipped whole)."""
    while True:
        line = stream.readline(MAX_RECORD_BYTES + 1)
        if not line:
            return
        if len(line) > MAX_RECORD_BYTES and not line.endswith(b"\n"):
            while (rest := stream.readline(1 << 20)) and not rest.endswith(b"\n"):
                pass
            yield None
            continue
        yield line


def rows_of_line(line: bytes, received: float) -> list[Row] | str:
    """The rows one JSONL line gives, or why it gives none."""
    try:
        record = json.loads(line)
    except (ValueError, RecursionError):
        return "not JSON"
    if not isinstance(record, dict):
        return "not a JSON object"
    kind = record.pop("kind", SYMPTOM)
    if kind not in (SYMPTOM, ALARM, ADVISORY):
        return f"kind {str(kind)[:20]!r} is not symptom, alarm or advisory"
    robot, joint = record.get("robot"), record.get("joint")
    if not isinstance(robot, str) or not isinstance(joint, int) or isinstance(joint, bool):
        return "no robot name or joint number"
    row = row_of(kind, robot, joint, record, received, heard=False)
    if isinstance(row, Rejection):
        return f"unusable record ({row.reason}{': ' + row.detail if row.detail else ''})"
    friction = friction_of(row)
    return [row] if friction is None else [row, friction]


def import_files(conn: Connection, paths: list[str], report: ImportReport | None = None) -> ImportReport:
    """Import every file of ``paths`` (in order); a file that cannot be read is named in ``unreadable``."""
    report = report or ImportReport()
    for path in paths:
        try:
            fd = open_regular(path)
        except (OSError, NotARegularFile) as exc:
            report.unreadable.append(f"{path}: {getattr(exc, 'reason', None) or getattr(exc, 'strerror', exc)}")
            continue
        with os.fdopen(fd, "rb") as stream:
            report.files += 1
            _import_stream(conn, path, stream, report)
    return report


def _import_stream(conn: Connection, path: str, stream: BinaryIO, report: ImportReport) -> None:
    batch: list[Row] = []
    for number, line in enumerate(_lines(stream), start=1):
        report.lines += 1
        if line is None:
            report.bad(f"{path}:{number}", f"longer than {MAX_RECORD_BYTES} bytes")
            continue
        if not line.strip():
            continue
        rows = rows_of_line(line, time.time())
        if isinstance(rows, str):
            report.bad(f"{path}:{number}", rows)
            continue
        batch.extend(rows)
        if len(batch) >= BATCH:
            _store(conn, batch, report)
            batch = []
    if batch:
        _store(conn, batch, report)


def _store(conn: Connection, rows: list[Row], report: ImportReport) -> None:
    result = insert_rows(conn, rows)
    report.stored += result.stored
    report.duplicates += result.duplicates
    report.friction_present += result.friction_present
    report.expired += result.expired
    for row in rows:
        report.robots.add(row.robot)
        low, high = report.span or (row.at, row.at)
        report.span = (min(low, row.at), max(high, row.at))
