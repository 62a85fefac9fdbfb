"""The historian's writer: rows from a bounded queue, stored in batches on a connection of its own.

Zenoh's threads only hand rows over (:meth:`Writer.offer` never blocks them). The writer thread takes up to
``batch_size`` rows or what came within ``batch_s``, stores them in one transaction
(:func:`~edge_monitor.historian.writes.insert_rows`) and goes on. When the database cannot take them
(the server is down or a read-only hot standby, the disk is full) the batch is kept and tried again with a
growing pause (0.5 s … 30 s) on a new connection, while the queue holds what keeps arriving; the outage is
logged when it starts and when it ends. A damaged or read-only SQLite file is no outage (no retry mends it): the writer
says so once, stores nothing more and counts every row it does not store (``lost_database``; ``unusable``
says why). A row the database refuses is found by halving the batch and counted (``rejected_database``);
the others are stored. Rows are lost only by a full queue (``lost_queue_full``), an unusable database, or a
stop whose wait for the database ran out (``lost_at_stop``): each is counted, ``lost`` is their sum, and
its range (robot, joint, kind, first … last cycle) kept for the report (:class:`LossLedger`).
"""

from __future__ import annotations

import logging
import queue
import threading
import time
from collections import Counter
from dataclasses import dataclass, field
from typing import Any, Callable

from edge_monitor.historian.database import (
    Connection,
    DatabaseUnavailable,
    DatabaseUnusable,
    RecordRefused,
    check_writable,
    connect,
)
from edge_monitor.historian.db_url import DbTarget
from edge_monitor.historian.identity import Row
from edge_monitor.historian.writes import WriteResult, insert_rows

log = logging.getLogger(__name__)

DEFAULT_QUEUE = 200_000          # rows waiting (≈ 2.6 h of 1 000 robots' symptoms and friction curves)
DEFAULT_BATCH = 500
DEFAULT_BATCH_S = 0.1
RETRY_S = (0.5, 1.0, 2.0, 5.0, 10.0, 30.0)
#: The ways a row is never stored: counter → how the summary says it.
LOST = {"lost_queue_full": "queue full", "lost_database": "database unusable", "lost_at_stop": "not stored at the stop"}


@dataclass
class LossLedger:
    """Rows never stored (:data:`LOST`), by (robot, joint, kind): count and cycle range."""

    ranges: dict[tuple[str, Any, str], list[Any]] = field(default_factory=dict)
    total: int = 0

    def add(self, row: Row) -> None:
        self.total += 1
        key = (row.robot, row.joint, row.kind)
        entry = self.ranges.setdefault(key, [0, row.cycle, row.cycle, row.utc, row.utc])
        entry[0] += 1
        if row.cycle is not None:
            entry[1] = row.cycle if entry[1] is None else min(entry[1], row.cycle)
            entry[2] = row.cycle if entry[2] is None else max(entry[2], row.cycle)
        entry[4] = row.utc or entry[4]

    def report(self) -> list[dict[str, Any]]:
        return [{"robot": r, "joint": j, "kind": k, "lost": n, "first_cycle": c0, "last_cycle": c1,
                 "first_utc": u0, "last_utc": u1} for (r, j, k), (n, c0, c1, u0, u1) in sorted(
                    self.ranges.items(), key=lambda item: (item[0][0], str(item[0][1]), item[0][2]))]


class Writer:
    """Stores offered rows in batches on its own thread; ``stats()`` says what happened to each."""

    def __init__(self, target: DbTarget, queue_size: int = DEFAULT_QUEUE, batch_size: int = DEFAULT_BATCH,
                 batch_s: float = DEFAULT_BATCH_S, on_stored: Callable[[WriteResult], None] | None = None) -> None:
        self.target = target
        self.batch_size, self.batch_s = int(batch_size), float(batch_s)
        self.on_stored = on_stored
        self.counts: Counter = Counter()
        self.lost = LossLedger()
        self.outages = 0
        self.down_since: float | None = None
        self.last_error: str | None = None
        self.unusable: str | None = None         # why the database takes no more rows (damaged, read-only)
        self._in_hand: list[Row] = []             # the batch being stored
        self._abandoned = False                   # stop() stopped waiting: what is left is counted lost
        self._refused: DatabaseUnusable | None = None    # a reconnection found the database unusable
        self._unreached: DatabaseUnavailable | None = None    # why the last reconnection failed (an outage)
        self._queue: queue.Queue[Row] = queue.Queue(maxsize=int(queue_size))
        self._stop = threading.Event()
        self._lock = threading.Lock()
        self._conn: Connection | None = None
        self._thread = threading.Thread(target=self._run, name="historian-writer", daemon=True)

    def start(self) -> "Writer":
        self._conn = connect(self.target)      # the schema is checked before anything is received
        try:
            check_writable(self._conn)          # a read-only file is refused now, not at the first batch
        except BaseException:
            self._conn.close()
            self._conn = None
            raise
        self._thread.start()
        return self

    def offer(self, row: Row) -> bool:
        """Queue ``row`` for storing (any thread, never blocks); False when the queue is full (counted)."""
        try:
            self._queue.put_nowait(row)
            return True
        except queue.Full:
            with self._lock:
                self.lost.add(row)
                self.counts["lost_queue_full"] += 1
                if self.lost.total in (1, 100) or self.lost.total % 10_000 == 0:
                    log.error("historian queue full (%d rows waiting for the database): %d row(s) lost so far, "
                              "their ranges are in the status", self._queue.qsize(), self.lost.total)
            return False

    def depth(self) -> int:
        return self._queue.qsize()

    @property
    def running(self) -> bool:
        """Whether the writer's thread still runs (after a stop that gave up waiting, until its write returns)."""
        return self._thread.is_alive()

    def stop(self, timeout: float = 30.0) -> None:
        """Store what is queued (up to ``timeout`` seconds), then close the connection; what is still not
        stored then is counted lost (``lost_at_stop``)."""
        self._stop.set()
        if self._thread.is_alive():
            self._thread.join(timeout)
        with self._lock:
            self._abandoned = True
            left = list(self._in_hand) if self._thread.is_alive() else []
            self._in_hand = []
        while True:
            try:
                left.append(self._queue.get_nowait())
            except queue.Empty:
                break
        if left:
            self._lose(left, "lost_at_stop")
            log.error("%d record(s) were not stored (%s); import the agents' JSONL files to fill them", len(left),
                      self.unusable or "the database stayed unavailable")
        if self._conn is not None:
            self._conn.close()
            self._conn = None

    def stats(self) -> dict[str, Any]:
        with self._lock:
            out: dict[str, Any] = dict(self.counts)
            out["lost"] = sum(self.counts[name] for name in LOST)
            out["lost_ranges"] = self.lost.report()
        out.update(queue_depth=self._queue.qsize(), outages=self.outages, database_unusable=self.unusable,
                   database_down_s=None if self.down_since is None else round(time.time() - self.down_since, 1),
                   last_database_error=self.last_error)
        return out

    # -- the thread --------------------------------------------------------------------------------

    def _run(self) -> None:
        while not self._abandoned:              # stop() gave up waiting: it counted what is left
            batch = self._take()
            if batch:
                try:
                    self._store(batch)
                except Exception as exc:       # a fault of the writer's own: counted like an unusable database
                    log.exception("the historian's writer failed")
                    self._give_up(f"the historian's writer failed: {exc}", batch)
            elif self._stop.is_set():
                return

    def _take(self) -> list[Row]:
        try:
            batch = [self._queue.get(timeout=self.batch_s)]
        except queue.Empty:
            return []
        deadline = time.monotonic() + self.batch_s
        while len(batch) < self.batch_size:
            left = deadline - time.monotonic()
            try:
                batch.append(self._queue.get(timeout=max(0.0, left)) if left > 0 else self._queue.get_nowait())
            except queue.Empty:
                break
        return batch

    def _store(self, batch: list[Row]) -> None:
        """Store ``batch``; retried while the database is unavailable (also while stopping: nothing queued
        is given up on a stop unless the thread's join times out); counted lost, never tried, once the
        database is unusable."""
        with self._lock:
            abandoned = self._abandoned
            self._in_hand = [] if abandoned else batch
        if abandoned or self.unusable is not None:      # stop() gave up waiting / the database is unusable
            self._lose(batch, "lost_at_stop" if abandoned else "lost_database")
            return
        attempt = 0
        try:
            while True:
                try:
                    self._write(batch)
                    self._recovered()
                    return
                except DatabaseUnusable as exc:
                    self._give_up(str(exc), batch)
                    return
                except DatabaseUnavailable as exc:
                    self._outage(exc)
                    pause = RETRY_S[min(attempt, len(RETRY_S) - 1)]
                    attempt += 1
                    time.sleep(pause)
                    if self._abandoned:
                        return
                    self._reconnect()
        finally:
            with self._lock:
                self._in_hand = []

    def _write(self, batch: list[Row]) -> None:
        if self._conn is None:
            if self._refused is not None:
                raise self._refused
            raise self._unreached or DatabaseUnavailable(f"{self.target.describe()}: not connected")
        try:
            result = insert_rows(self._conn, batch)
        except RecordRefused as exc:
            if len(batch) == 1:
                self._count("rejected_database")
                log.warning("record %s %s/%s cycle %s not stored: %s", batch[0].kind, batch[0].robot, batch[0].joint,
                            batch[0].cycle, exc)
                return
            middle = len(batch) // 2
            self._write(batch[:middle])
            self._write(batch[middle:])
            return
        with self._lock:
            self.counts["stored"] += result.stored
            self.counts["duplicates"] += result.duplicates
            self.counts["friction_present"] += result.friction_present
            self.counts["health_sampled_out"] += result.health_sampled_out
            self.counts["expired"] += result.expired
            self.counts["batches"] += 1
            for kind, n in result.by_kind.items():
                self.counts[f"stored_{kind}"] += n
        if self.on_stored is not None:
            self.on_stored(result)

    def _count(self, name: str, n: int = 1) -> None:
        with self._lock:
            self.counts[name] += n

    def _lose(self, rows: list[Row], reason: str) -> None:
        with self._lock:
            for row in rows:
                self.lost.add(row)
            self.counts[reason] += len(rows)

    def _give_up(self, why: str, batch: list[Row]) -> None:
        """The database is unusable: no more retries; ``batch`` and every later row are counted lost."""
        self.last_error = why
        if self.unusable is None:
            self.unusable = why
            self.down_since = None
            log.error("database unusable, nothing more is stored (each record is counted lost, with its range in "
                      "the status): %s", why)
        self._lose(batch, "lost_database")

    def _outage(self, exc: Exception) -> None:
        self.last_error = str(exc)
        if self.down_since is None:
            self.down_since = time.time()
            self.outages += 1
            log.error("database unavailable: %s; records wait in memory (%d queued) and are stored when it is back",
                      exc, self._queue.qsize())

    def _recovered(self) -> None:
        if self.down_since is not None:
            log.warning("database available again after %.1f s; %d record(s) waiting", time.time() - self.down_since,
                        self._queue.qsize())
            self.down_since = None

    def _reconnect(self) -> None:
        if self._conn is not None:
            self._conn.close()
            self._conn = None
        try:
            self._conn = connect(self.target)
            self._unreached = None
        except DatabaseUnusable as exc:
            self._refused = exc                   # the next write says so: given up, not retried
        except DatabaseUnavailable as exc:       # e.g. the server still down, or still a read-only standby
            self._unreached = exc
            self.last_error = str(exc)
