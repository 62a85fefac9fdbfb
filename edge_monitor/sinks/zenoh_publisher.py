"""Zenoh publication of the agent's outputs (key space of docs/OUTPUTS.md) and a matching subscriber.

Keys (JSON payloads, encoding ``application/json``):

* ``edge/<robot>/<joint>/symptom`` and ``.../alarm``: advanced publishers (zenoh.ext) with a cache,
  sample-miss detection and publisher detection, RELIABLE with congestion control BLOCK, so a late or
  briefly disconnected subscriber recovers recent records and learns about the ones it lost.
* ``edge/<robot>/<joint>/friction`` and ``edge/<robot>/agent/health``: plain publishers, DROP
  (telemetry: the newest value matters, old ones may go).
* ``edge/<robot>/agent``: liveliness token while the agent runs.
* ``edge/<robot>/<joint>/state``: queryable answering with ``state_provider(joint)`` (read-only); a
  joint the agent does not monitor, asked by name, gets ``reply_err`` listing the joints it monitors.

Publishing never raises: a failure is logged once per kind and counted as undelivered.
"""

from __future__ import annotations

import json
import logging
import threading
from collections import Counter
from dataclasses import dataclass
from typing import Any, Callable, Iterable

import zenoh
import zenoh.ext as zext

from edge_monitor.records import Advisory, Alarm, Health, Symptom, to_json
from edge_monitor.sinks.keys import (
    ADVISORY,
    ALARM,
    FRICTION,
    HEALTH,
    KINDS,
    STATE,
    SYMPTOM,
    agent_key,
    check_robot_name,
    joint_key,
    parse_key,
    robot_of,
)

log = logging.getLogger(__name__)

_STAT_NAMES = {SYMPTOM: "symptoms", ALARM: "alarms", ADVISORY: "advisories", FRICTION: "friction", HEALTH: "health"}

DEFAULT_CACHE_SIZE = 256          # samples per advanced publisher (≈ 2 h of 30 s cycles)
HEARTBEAT_S = 0.5                 # sample-miss heartbeat period (sent only after new samples), s


def not_monitored(robot: str, joint: int, monitored: list[int]) -> dict[str, Any]:
    """The error body of a state query for a joint the agent does not monitor: which ones it does."""
    shown = ", ".join(map(str, monitored[:32])) + (", …" if len(monitored) > 32 else "")
    return {"error": f"robot {robot} does not monitor joint {joint} "
                     f"({f'it monitors joint(s) {shown}' if monitored else 'it has no joint yet'})",
            "unknown_joint": joint, "joints": monitored}


class SymptomPublisher:
    """Declares and feeds the agent's Zenoh publishers for one robot.

    ``joints``: joint numbers known at start (others are declared on first use).
    ``cache_size``: samples kept per symptom/alarm publisher for late subscribers.
    ``state_provider(joint) -> dict``: answers ``edge/<robot>/<joint>/state`` queries; ``None``: no queryable.
    ``joints_provider() -> joints``: every joint the agent knows, answered for before its first symptom too.
    """

    def __init__(self, session: zenoh.Session, robot: str, joints: Iterable[int],
                 cache_size: int = DEFAULT_CACHE_SIZE,
                 state_provider: Callable[[int], dict] | None = None,
                 joints_provider: Callable[[], Iterable[int]] | None = None) -> None:
        if cache_size < 1:
            raise ValueError(f"cache_size={cache_size} must be >= 1; fix the zenoh cache size")
        self.session = session
        self.robot = check_robot_name(robot)
        self.cache_size = int(cache_size)
        self.state_provider = state_provider
        self.joints_provider = joints_provider
        self.published = {kind: 0 for kind in KINDS}
        self.undelivered = {kind: 0 for kind in KINDS}
        self.queries_answered = 0
        self.republished = 0
        self._failed_kinds: set[str] = set()
        self._lock = threading.Lock()
        self._joint_publishers: dict[int, dict[str, Any]] = {}
        self._closed = False
        self._health = session.declare_publisher(
            agent_key(robot, HEALTH), encoding=zenoh.Encoding.APPLICATION_JSON,
            congestion_control=zenoh.CongestionControl.DROP, reliability=zenoh.Reliability.RELIABLE)
        self._token = session.liveliness().declare_token(agent_key(robot))
        self._queryable = None
        if state_provider is not None:
            self._queryable = session.declare_queryable(joint_key(robot, "*", STATE), self._answer_state)
        for joint in joints:
            self._publishers_for(int(joint))

    # -- declaration -------------------------------------------------------------------------------

    def _advanced(self, key: str) -> Any:
        return zext.declare_advanced_publisher(
            self.session, key, encoding=zenoh.Encoding.APPLICATION_JSON,
            congestion_control=zenoh.CongestionControl.BLOCK, reliability=zenoh.Reliability.RELIABLE,
            cache=zext.CacheConfig(max_samples=self.cache_size),
            # sporadic: the heartbeat goes out only when something was published since the last one. A
            # periodic one costs 2 messages a second per key whatever the load: 36 per 6-joint robot, and a
            # plant router saturated at a few hundred idle robots (docs/BENCHMARKS.md, "The historian")
            sample_miss_detection=zext.MissDetectionConfig(heartbeat=None, sporadic_heartbeat=HEARTBEAT_S),
            publisher_detection=True)

    def _publishers_for(self, joint: int) -> dict[str, Any]:
        with self._lock:
            publishers = self._joint_publishers.get(joint)
            if publishers is None:
                publishers = {
                    SYMPTOM: self._advanced(joint_key(self.robot, joint, SYMPTOM)),
                    ALARM: self._advanced(joint_key(self.robot, joint, ALARM)),
                    ADVISORY: self._advanced(joint_key(self.robot, joint, ADVISORY)),
                    FRICTION: self.session.declare_publisher(
                        joint_key(self.robot, joint, FRICTION), encoding=zenoh.Encoding.APPLICATION_JSON,
                        congestion_control=zenoh.CongestionControl.DROP),
                }
                self._joint_publishers[joint] = publishers
            return publishers

    @property
    def joints(self) -> list[int]:
        return sorted(self._joint_publishers)

    def has_subscriber(self) -> bool:
        """True once this session knows a subscriber whose key expression covers this agent's health key
        (``edge/<robot>/health``: ``edge/**`` and ``edge/<robot>/**`` do, a joint's keys alone do not).

        Samples put before that are routed nowhere; a subscriber that connects later recovers them
        from the publishers' caches only if it sees them published after it came (a Zenoh race of
        "publication before discovery"), so wait for this before a burst that must arrive whole."""
        status: Any = self._health.matching_status     # MatchingStatus (the type stubs say bool)
        return bool(status.matching)

    # -- publication -------------------------------------------------------------------------------

    def publish_symptom(self, record: dict) -> bool:
        """Publish one per-cycle symptom record; True when handed to Zenoh."""
        return self._put(SYMPTOM, record.get("joint"), record)

    def republish_symptoms(self, records: list[dict]) -> int:
        """Publish again symptom records of an earlier run, in order: the last ``cache_size`` of each joint
        (e.g. the tail of the JSONL file at a restart: a crash can cut off puts Zenoh had not sent yet,
        and this run's caches start empty). Subscribers see them twice when they had them already.
        Counted in ``symptoms_republished``; returns how many were handed to Zenoh."""
        remaining = Counter(r.get("joint") for r in records)
        for record in records:
            joint = record.get("joint")
            remaining[joint] -= 1
            if remaining[joint] < self.cache_size and self._put(SYMPTOM, joint, record, count=False):
                self.republished += 1
        return self.republished

    def publish_alarm(self, record: dict) -> bool:
        """Publish one alarm raised/cleared record."""
        return self._put(ALARM, record.get("joint"), record)

    def publish_advisory(self, record: dict) -> bool:
        """Publish one advisory (not a fault: e.g. an operating condition outside the learned range)."""
        return self._put(ADVISORY, record.get("joint"), record)

    def publish_friction(self, record: dict) -> bool:
        """Publish the friction curve of a cycle (``Symptom.friction_record()``)."""
        return self._put(FRICTION, record.get("joint"), record)

    def publish_health(self, record: dict) -> bool:
        """Publish the agent's health counters/rates."""
        record = {"robot": self.robot, "symptoms_published": self.published[SYMPTOM],
                  "symptoms_undelivered": self.undelivered[SYMPTOM], **record}
        return self._put(HEALTH, None, record)

    def _put(self, kind: str, joint: Any, record: dict, count: bool = True) -> bool:
        try:
            if self._closed:
                raise RuntimeError("publisher is closed")
            payload = to_json(record)
            publisher = self._health if kind == HEALTH else self._publishers_for(int(joint))[kind]
            publisher.put(payload)
        except Exception as exc:  # the agent never dies of output
            self.undelivered[kind] += 1
            if kind not in self._failed_kinds:
                self._failed_kinds.add(kind)
                log.warning("zenoh %s not delivered (further failures of this kind are only counted): %s",
                            kind, exc)
            return False
        if count:
            self.published[kind] += 1
        return True

    def stats(self) -> dict[str, int]:
        """Counters: ``symptoms_published``, ``symptoms_undelivered``, ``alarms_…``, ``friction_…``,
        ``health_…``, ``state_queries`` and ``symptoms_republished``."""
        out: dict[str, int] = {}
        for kind in KINDS:
            name = _STAT_NAMES[kind]
            out[f"{name}_published"] = self.published[kind]
            out[f"{name}_undelivered"] = self.undelivered[kind]
        out["state_queries"] = self.queries_answered
        out["symptoms_republished"] = self.republished
        return out

    # -- queryable ---------------------------------------------------------------------------------

    def _answer_state(self, query: zenoh.Query) -> None:
        """Reply with the state of every joint whose state key the query selects; a query for exactly one
        joint this agent does not monitor gets ``reply_err`` saying which joints it monitors."""
        try:
            selector = zenoh.KeyExpr(str(query.key_expr))
            known = set(self.joints_provider()) if self.joints_provider is not None else set()
            monitored = sorted(known | set(self.joints))
            for joint in monitored:
                key = zenoh.KeyExpr(joint_key(self.robot, joint, STATE))
                if key.intersects(selector):
                    state = self.state_provider(joint) if self.state_provider else {}
                    query.reply(key, to_json(state), encoding=zenoh.Encoding.APPLICATION_JSON)
            parts = parse_key(str(query.key_expr))       # wildcards never parse: one joint asked by name
            if parts is not None and parts.joint is not None and parts.joint not in monitored:
                query.reply_err(to_json(not_monitored(self.robot, parts.joint, monitored)),
                                encoding=zenoh.Encoding.APPLICATION_JSON)
            self.queries_answered += 1
        except Exception as exc:  # a queryable callback must not raise into zenoh
            log.warning("state query %s failed: %s", query.key_expr, exc)
            try:
                query.reply_err(to_json({"error": str(exc)}), encoding=zenoh.Encoding.APPLICATION_JSON)
            except Exception:
                pass

    def close(self) -> None:
        """Undeclare every publisher, the token and the queryable (idempotent)."""
        if self._closed:
            return
        self._closed = True
        entities: list[Any] = [self._health, self._token, self._queryable]
        for publishers in self._joint_publishers.values():
            entities.extend(publishers.values())
        for entity in entities:
            if entity is None:
                continue
            try:
                entity.undeclare()
            except Exception as exc:
                log.debug("undeclare failed: %s", exc)

    def __enter__(self) -> "SymptomPublisher":
        return self

    def __exit__(self, *_exc: object) -> None:
        self.close()


@dataclass(frozen=True)
class ReceivedRecord:
    """One record received from the ``edge/**`` key space."""

    key: str
    robot: str
    joint: int | None          # None for agent-level keys (health)
    kind: str                  # "symptom" | "alarm" | "friction" | "health" | other last key segment
    record: dict


class SymptomSubscriber:
    """Advanced subscriber on ``key_expr`` collecting decoded records (thread-safe) and counting misses.

    ``history``: query the advanced publishers' caches (also of publishers that appear later).
    ``callback(ReceivedRecord)``: called on Zenoh's thread for each record, in addition to collection.
    ``keep``: collect records in memory (off for long-running views that only use the callback).
    """

    def __init__(self, session: zenoh.Session, key_expr: str = "edge/**", history: bool = True,
                 callback: Callable[[ReceivedRecord], None] | None = None, keep: bool = True,
                 max_history: int = DEFAULT_CACHE_SIZE) -> None:
        self.session = session
        self.callback = callback
        self.keep = keep
        self.misses = 0
        self.decode_errors = 0
        self.agents: set[str] = set()
        self._records: list[ReceivedRecord] = []
        self._condition = threading.Condition()
        history_config = (zext.HistoryConfig(detect_late_publishers=True, max_samples=max_history)
                          if history else None)
        self._subscriber = zext.declare_advanced_subscriber(
            session, key_expr, self._on_sample, history=history_config,
            recovery=zext.RecoveryConfig(periodic_queries=None, heartbeat=True))
        self._miss_listener = self._subscriber.sample_miss_listener(self._on_miss)
        self._liveliness = session.liveliness().declare_subscriber(
            agent_key("*"), self._on_liveliness, history=True)

    def _on_sample(self, sample: zenoh.Sample) -> None:
        key = str(sample.key_expr)
        parsed = parse_key(key)
        try:
            record = json.loads(sample.payload.to_string())
            if parsed is None or not isinstance(record, dict):
                raise ValueError(f"unexpected key or payload on {key}")
        except Exception as exc:
            with self._condition:
                self.decode_errors += 1
            log.debug("undecodable sample on %s: %s", key, exc)
            return
        received = ReceivedRecord(key, parsed.robot, parsed.joint, parsed.kind, record)
        with self._condition:
            if self.keep:
                self._records.append(received)
            self._condition.notify_all()
        if self.callback is not None:
            try:
                self.callback(received)
            except Exception as exc:
                log.warning("subscriber callback failed on %s: %s", key, exc)

    def _on_miss(self, miss: Any) -> None:
        with self._condition:
            self.misses += int(miss.nb)
        log.warning("missed %d sample(s) from publisher %s", miss.nb, miss.source)

    def _on_liveliness(self, sample: zenoh.Sample) -> None:
        robot = robot_of(str(sample.key_expr))
        if robot is None:
            return
        with self._condition:
            if sample.kind == zenoh.SampleKind.PUT:
                self.agents.add(robot)
            else:
                self.agents.discard(robot)
            self._condition.notify_all()

    def records(self, kind: str | None = None) -> list[dict]:
        """Copies of the received record dicts, in arrival order, optionally of one kind."""
        with self._condition:
            return [r.record for r in self._records if kind is None or r.kind == kind]

    def received(self) -> list[ReceivedRecord]:
        with self._condition:
            return list(self._records)

    def count(self, kind: str | None = None) -> int:
        with self._condition:
            return sum(1 for r in self._records if kind is None or r.kind == kind)

    def wait_for(self, predicate: Callable[["SymptomSubscriber"], bool], timeout: float) -> bool:
        """Block until ``predicate(self)`` holds or ``timeout`` seconds pass; returns whether it holds."""
        with self._condition:  # an RLock: the predicate may call records()/count()
            return self._condition.wait_for(lambda: predicate(self), timeout=timeout)

    def close(self) -> None:
        for entity in (self._miss_listener, self._subscriber, self._liveliness):
            try:
                entity.undeclare()
            except Exception as exc:
                log.debug("undeclare failed: %s", exc)

    def __enter__(self) -> "SymptomSubscriber":
        return self

    def __exit__(self, *_exc: object) -> None:
        self.close()


class ZenohSink:
    """Sink adapter: publishes symptoms, friction curves, alarms and health through a publisher."""

    def __init__(self, publisher: SymptomPublisher) -> None:
        self.publisher = publisher

    def on_symptom(self, symptom: Symptom) -> None:
        self.publisher.publish_symptom(symptom.to_dict())
        self.publisher.publish_friction(symptom.friction_record())

    def on_alarm(self, alarm: Alarm) -> None:
        self.publisher.publish_alarm(alarm.to_dict())

    def on_advisory(self, advisory: Advisory) -> None:
        self.publisher.publish_advisory(advisory.to_dict())

    def on_health(self, health: Health) -> None:
        self.publisher.publish_health(health.to_dict())

    def close(self) -> None:
        self.publisher.close()
