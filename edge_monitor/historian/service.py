"""``edge-monitor historian``: subscribe to every agent through the plant's Zenoh router, store what they
publish exactly once, and answer history questions on ``edge/history/**``.

Subscriptions (read only: the historian puts nothing on any agent's keys):

* ``edge/**`` through an advanced subscriber with history and recovery (``SymptomSubscriber``): live
  records, and on start (or when an agent appears) what each agent's publishers still cache — the last
  256 symptoms, alarms and advisories per joint, ≈ 2 h at a cycle per 30 s: a historian that was down
  for less catches up by itself; a longer gap is reported and filled by ``historian import``.
* ``edge/*/*/maintenance``: maintenance requests operators put (text payloads), stored as requests.
* liveliness ``edge/*/agent``: which agents are up now (the fleet answer's ``online``).

The queryable ``edge/history/<records|alarms|fleet|gaps|daily|status>`` answers from a database thread
of its own, never on Zenoh's (a burst of questions holds neither the records nor the status question): at
most ``MAX_WAITING`` questions wait, more get a counted "busy, retry" reply, each answer bounded
(docs/HISTORIAN.md).
"""

from __future__ import annotations

import logging
import threading
import time
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field
from typing import Any

import zenoh

from edge_monitor.historian.database import Connection, DatabaseError, connect
from edge_monitor.historian.db_url import DbTarget
from edge_monitor.historian.gaps import describe_gaps, find_gaps
from edge_monitor.historian.identity import (
    STORED_KINDS,
    HealthSampling,
    Rejection,
    friction_of,
    maintenance_record,
    row_of,
)
from edge_monitor.historian.retention import Retention, thin
from edge_monitor.historian.writer import DEFAULT_QUEUE, Writer
from edge_monitor.historian.zenoh_answers import HistoryQueryable
from edge_monitor.sinks.keys import MAINTENANCE, PREFIX, parse_key
from edge_monitor.sinks.zenoh_publisher import ReceivedRecord, SymptomSubscriber

log = logging.getLogger(__name__)

THIN_EVERY_S = 3600.0              # how often retention runs
GAP_CHECK_DELAY_S = 30.0           # after start: the caches have answered; gaps are reported then


@dataclass(frozen=True)
class HistorianConfig:
    """What the service does besides storing: retention, health sampling, queue bound, gap report."""

    retention: Retention = field(default_factory=Retention)
    health: HealthSampling = field(default_factory=HealthSampling)
    queue_size: int = DEFAULT_QUEUE
    gap_window_s: float = 86400.0          # the start-up gap report looks this far back
    history: bool = True                   # ask the agents' caches on start

    def __post_init__(self) -> None:
        if not 1000 <= self.queue_size <= 10_000_000:
            raise ValueError(f"queue size {self.queue_size} must be 1000 … 10000000 records; fix --queue")


class Historian:
    """The running service: ``start()``, ``tick()`` from the main loop, ``close()``; ``status()`` counters."""

    def __init__(self, session: zenoh.Session, target: DbTarget, config: HistorianConfig = HistorianConfig()) -> None:
        self.session = session
        self.target = target
        self.config = config
        self.started = time.time()
        self.rejected: dict[str, int] = {}
        self.received = 0
        self.ignored = 0
        self.writer = Writer(target, queue_size=config.queue_size)
        self._reads: Connection | None = None
        self._read_lock = threading.Lock()
        self._entities: list[Any] = []
        self._subscriber: SymptomSubscriber | None = None
        self._queryable: HistoryQueryable | None = None
        self._pool = ThreadPoolExecutor(max_workers=1, thread_name_prefix="historian-query")
        self._next_thin = time.monotonic()
        self._gap_check_at: float | None = time.monotonic() + GAP_CHECK_DELAY_S
        self.gaps_reported: list[dict[str, Any]] = []

    def start(self) -> "Historian":
        """Open the database (migrating it), then subscribe and declare the queryable."""
        self.writer.start()
        self._reads = connect(self.target, migrate=False)
        self._subscriber = SymptomSubscriber(self.session, f"{PREFIX}/**", history=self.config.history,
                                             callback=self._on_record, keep=False)
        self._entities.append(self.session.declare_subscriber(f"{PREFIX}/*/*/{MAINTENANCE}", self._on_maintenance))
        self._queryable = HistoryQueryable(self.session, self._answer_in_pool, self.status)
        return self

    # -- receiving ---------------------------------------------------------------------------------

    def _on_record(self, received: ReceivedRecord) -> None:
        if received.kind not in STORED_KINDS:       # e.g. an operator's acknowledgement request
            self.ignored += 1
            return
        self.received += 1
        now = time.time()
        row = row_of(received.kind, received.robot, received.joint, received.record, now, self.config.health)
        if isinstance(row, Rejection):
            self.rejected[row.reason] = self.rejected.get(row.reason, 0) + 1
            return
        self.writer.offer(row)
        friction = friction_of(row)
        if friction is not None:
            self.writer.offer(friction)

    def _on_maintenance(self, sample: zenoh.Sample) -> None:
        try:
            parts = parse_key(str(sample.key_expr))
            if parts is None or parts.joint is None:
                self.rejected["maintenance_key"] = self.rejected.get("maintenance_key", 0) + 1
                return
            attachment = sample.attachment.to_bytes() if sample.attachment is not None else None
            stamp = str(sample.timestamp) if sample.timestamp is not None else None
            now = time.time()
            record = maintenance_record(parts.robot, parts.joint, sample.payload.to_bytes(), attachment, stamp, now)
            row = row_of(MAINTENANCE, parts.robot, parts.joint, record, now)
            if not isinstance(row, Rejection):
                self.writer.offer(row)
        except Exception as exc:     # a subscriber callback never raises into Zenoh
            log.warning("maintenance request on %s not stored: %s", sample.key_expr, exc)

    # -- answering ---------------------------------------------------------------------------------

    def _answer_in_pool(self, ask: Any) -> Any:
        return self._pool.submit(self._answer, ask)

    def _answer(self, ask: Any) -> Any:
        with self._read_lock:
            if self._reads is None:
                self._reads = connect(self.target, migrate=False)
            try:
                return ask(self._reads, self.online())
            except DatabaseError:
                self._reads.close()
                self._reads = None
                raise

    @property
    def unusable(self) -> str | None:
        """Why the database takes no more records (damaged, read-only), or None: the service should stop."""
        return self.writer.unusable

    def online(self) -> set[str]:
        return set(self._subscriber.agents) if self._subscriber is not None else set()

    # -- housekeeping ------------------------------------------------------------------------------

    def tick(self) -> None:
        """Periodic work from the main loop: retention once an hour, the gap report after start."""
        now = time.monotonic()
        if now >= self._next_thin:
            self._next_thin = now + THIN_EVERY_S
            self._pool.submit(self._thin)
        if self._gap_check_at is not None and now >= self._gap_check_at:
            self._gap_check_at = None
            self._pool.submit(self._report_gaps)

    def _thin(self) -> None:
        try:
            with self._read_lock:
                conn = connect(self.target, migrate=False)
                try:
                    thin(conn, self.config.retention)
                finally:
                    conn.close()
        except DatabaseError as exc:
            log.warning("retention did not run: %s (tried again in an hour)", exc)

    def _report_gaps(self) -> None:
        try:
            self.gaps_reported = self._answer(lambda conn, _online: find_gaps(
                conn, since=time.time() - self.config.gap_window_s))
        except DatabaseError as exc:
            log.warning("gap report not made: %s", exc)
            return
        if self.gaps_reported:
            log.warning("after catching up, cycles missing from the history (fill them with `edge-monitor historian "
                        "import` of the agents' JSONL files):\n%s", describe_gaps(self.gaps_reported))
        else:
            log.info("after catching up: no cycles missing in the last %.0f h", self.config.gap_window_s / 3600)

    def status(self) -> dict[str, Any]:
        """Counters: received, rejected by reason, what the writer did, Zenoh misses, agents online."""
        subscriber = self._subscriber
        return {"database": self.target.describe(), "uptime_s": round(time.time() - self.started, 1),
                "received": self.received, "rejected": dict(self.rejected), "ignored": self.ignored,
                "zenoh_missed": subscriber.misses if subscriber else 0,
                "zenoh_undecodable": subscriber.decode_errors if subscriber else 0,
                "agents_online": sorted(self.online()), "gaps_at_start": self.gaps_reported,
                "questions": self._queryable.counters() if self._queryable is not None else None,
                **self.writer.stats()}

    def close(self) -> dict[str, Any]:
        """Stop receiving, store what is queued, close; the final status."""
        for entity in [self._queryable, self._subscriber, *self._entities]:
            if entity is None:
                continue
            try:
                entity.close() if hasattr(entity, "close") else entity.undeclare()
            except Exception as exc:
                log.debug("undeclare failed: %s", exc)
        self.writer.stop()                  # what it could not store is counted lost (and logged) there
        self._pool.shutdown(wait=True, cancel_futures=True)
        if self._queryable is not None:
            self._queryable.drain()         # the questions still waiting are told the historian stops
        if self._reads is not None:
            self._reads.close()
        return self.status()
