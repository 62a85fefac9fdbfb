"""Maintenance declarations over Zenoh: a put on ``edge/<robot>/<joint>/maintenance`` asks the agent to
relearn that joint's nominal models (gearbox replaced or serviced) and to clear its alarms.

Authentication belongs to the Zenoh router (mTLS + access control, docs/SECURITY.md); the agent adds a
local defence that does not depend on the router being configured well, :class:`MaintenanceGate`:
remote declarations are refused unless explicitly allowed, only exact keys ``edge/<this robot>/<joint>/
maintenance`` count (no wildcards), a joint the robot cannot have (≥ ``MAX_JOINTS``) or the agent does
not monitor is refused (``unknown_joint``), each joint accepts at most ``max_per_joint`` declarations per
``window_s`` seconds, and every decision is logged with the key, the source information Zenoh carries
and the (truncated) payload; refusals are counted and their logging is rate-limited.
"""

from __future__ import annotations

import logging
import math
import threading
import time
from collections import deque
from dataclasses import dataclass
from typing import Any, Callable

from edge_monitor.errors import ConfigError
from edge_monitor.sinks.keys import MAINTENANCE, check_robot_name, joint_key, parse_key
from protocol.frames import MAX_JOINTS

log = logging.getLogger(__name__)

DEFAULT_MAX_PER_JOINT = 1                          # accepted maintenance declarations per joint ...
DEFAULT_WINDOW_S = 600.0                           # ... per this many seconds
DEFAULT_LOG_INTERVAL_S = 60.0                      # at most one refusal log line per reason and joint per this
PAYLOAD_LOG_CHARS = 200                            # payload characters kept in log lines


@dataclass(frozen=True)
class MaintenanceConfig:
    """Remote maintenance over Zenoh (the ``[maintenance]`` table), validated once, here.

    ``remote``: accept declarations put on Zenoh at all (off by default: ``edge-monitor run
    --maintenance J`` at start always works); at most ``max_per_joint`` accepted per joint in any
    ``window_s`` seconds.
    """

    remote: bool = False
    max_per_joint: int = DEFAULT_MAX_PER_JOINT
    window_s: float = DEFAULT_WINDOW_S

    def __post_init__(self) -> None:
        if not (isinstance(self.max_per_joint, int) and 1 <= self.max_per_joint <= 1000):
            raise ConfigError(f"maintenance.max_per_joint: must be 1 … 1000, got {self.max_per_joint!r}")
        if not (math.isfinite(self.window_s) and 1.0 <= self.window_s <= 30 * 86400):
            raise ConfigError(f"maintenance.window_s: must be 1 … 2592000 s, got {self.window_s!r}")


def gate_maintenance(session: Any, robot: str, config: MaintenanceConfig,
                     declare: Callable[[int], Any]) -> tuple["MaintenanceGate", Any]:
    """Subscribe to ``edge/<robot>/*/maintenance`` through a :class:`MaintenanceGate`; accepted puts
    call ``declare(joint)``. Returns the gate (its ``stats()`` go into health) and the subscriber."""
    gate = MaintenanceGate(robot, allow=config.remote, max_per_joint=config.max_per_joint, window_s=config.window_s)
    return gate, session.declare_subscriber(gate.key_expr, gate.callback(declare))


@dataclass(frozen=True)
class MaintenanceDecision:
    """Outcome of :meth:`MaintenanceGate.decide`; ``joint`` is None when the key names no joint of this robot."""

    accepted: bool
    joint: int | None
    reason: str          # "accepted" | "disabled" | "bad_key" | "unknown_joint" | "rate_limited"


def _printable(text: str, limit: int) -> str:
    shown = text[:limit].encode("unicode_escape").decode("ascii")
    return shown + (f"… ({len(text)} chars)" if len(text) > limit else "")


def _to_text(value: Any) -> str:
    """Payload/attachment (ZBytes, bytes, str, None) as text for logs; undecodable bytes as escapes."""
    if value is None:
        return ""
    if hasattr(value, "to_bytes"):
        value = value.to_bytes()
    if isinstance(value, (bytes, bytearray, memoryview)):
        return bytes(value).decode("utf-8", errors="backslashreplace")
    return str(value)


def describe_source(sample: Any) -> str:
    """What Zenoh tells about a sample's origin: ``source_info`` (zid/eid/sn) when the publisher set it,
    else "unknown". It is not authenticated; the router's mTLS + access control is what authenticates."""
    try:
        info = getattr(sample, "source_info", None)
    except Exception:   # unstable API: absent or failing in some builds
        info = None
    if info is None:
        return "unknown"
    try:
        return f"zid={info.source_id.zid} eid={info.source_id.eid} sn={info.source_sn}"
    except Exception:
        return str(info)


class MaintenanceGate:
    """Decides whether a remote maintenance declaration (a put on ``edge/<robot>/<joint>/maintenance``)
    is accepted. Thread-safe; pure logic (Zenoh samples are read by duck typing).

    ``robot``: this agent's robot name; only exact keys for it count.
    ``allow``: accept remote declarations at all (off by default: the CLI ``--maintenance`` still works).
    ``max_per_joint`` / ``window_s``: at most that many accepted declarations per joint in any sliding
    window of ``window_s`` seconds; the excess is refused and counted.
    ``log_interval_s``: per (reason, joint), refusals are logged at most once per interval; the next
    line says how many were not logged. Accepted declarations are always logged.
    ``clock``: monotonic seconds (injectable for tests).
    """

    def __init__(self, robot: str, allow: bool = False, max_per_joint: int = DEFAULT_MAX_PER_JOINT,
                 window_s: float = DEFAULT_WINDOW_S, logger: logging.Logger | None = None,
                 log_interval_s: float = DEFAULT_LOG_INTERVAL_S, payload_chars: int = PAYLOAD_LOG_CHARS,
                 clock: Callable[[], float] = time.monotonic) -> None:
        check_robot_name(robot)
        if int(max_per_joint) < 1:
            raise ValueError(f"max_per_joint={max_per_joint} must be >= 1 (use allow=False to refuse all)")
        if not (math.isfinite(window_s) and window_s > 0):
            raise ValueError(f"window_s={window_s} must be a positive number of seconds")
        if not (math.isfinite(log_interval_s) and log_interval_s >= 0):
            raise ValueError(f"log_interval_s={log_interval_s} must be >= 0 seconds")
        self.robot = robot
        self.allow = bool(allow)
        self.max_per_joint = int(max_per_joint)
        self.window_s = float(window_s)
        self.log_interval_s = float(log_interval_s)
        self.payload_chars = int(payload_chars)
        self.log = logger or log
        self.clock = clock
        self.counts = {"accepted": 0, "disabled": 0, "bad_key": 0, "unknown_joint": 0, "rate_limited": 0}
        self._accepted_at: dict[int, deque[float]] = {}
        self._last_log: dict[tuple[str, int | None], tuple[float, int]] = {}   # → (time, suppressed since)
        self._lock = threading.Lock()

    @property
    def key_expr(self) -> str:
        """What the agent subscribes to: ``edge/<robot>/*/maintenance``."""
        return joint_key(self.robot, "*", MAINTENANCE)

    def decide(self, key: str, payload: Any = None, source: str = "unknown", attachment: Any = None,
               now: float | None = None) -> MaintenanceDecision:
        """Accept or refuse one declaration, count it and log it (key, source, attachment, payload)."""
        now = self.clock() if now is None else float(now)
        parts = parse_key(key)
        joint = parts.joint if parts is not None and parts.robot == self.robot and parts.kind == MAINTENANCE else None
        with self._lock:
            if joint is None:
                reason = "bad_key"
            elif not self.allow:
                reason = "disabled"
            elif joint >= MAX_JOINTS:
                reason = "unknown_joint"
            elif self._rate_limited(joint, now):
                reason = "rate_limited"
            else:
                reason = "accepted"
                self._accepted_at.setdefault(joint, deque()).append(now)
                if len(self._accepted_at) > 1024:      # bound memory: forget joints idle for a window
                    for idle in [j for j, t in self._accepted_at.items() if now - t[-1] >= self.window_s]:
                        del self._accepted_at[idle]
            self.counts[reason] += 1
            suppressed = self._log_budget(reason, joint, now)
        if suppressed is not None:
            self._log_decision(reason, key, joint, payload, source, attachment, suppressed)
        return MaintenanceDecision(reason == "accepted", joint, reason)

    def decide_sample(self, sample: Any, now: float | None = None) -> MaintenanceDecision:
        """:meth:`decide` for a ``zenoh.Sample`` (key_expr, payload, attachment, source_info)."""
        return self.decide(str(sample.key_expr), getattr(sample, "payload", None), describe_source(sample),
                           getattr(sample, "attachment", None), now)

    def callback(self, declare: Callable[[int], Any]) -> Callable[[Any], None]:
        """A Zenoh subscriber callback: gate each sample, then ``declare(joint)`` when accepted.
        Never raises into Zenoh's thread; a failing ``declare`` is logged with the key."""

        def on_sample(sample: Any) -> None:
            try:
                decision = self.decide_sample(sample)
                if decision.accepted and decision.joint is not None:
                    try:
                        declare(decision.joint)
                    except ValueError as exc:           # a joint the agent does not monitor: refused after all
                        self._refuse_after_all(decision.joint, str(getattr(sample, "key_expr", "?")), str(exc))
            except Exception as exc:
                self.log.error("maintenance declaration on %s not applied: %s", getattr(sample, "key_expr", "?"), exc)

        return on_sample

    def stats(self) -> dict[str, int]:
        """Counters for health records: ``maintenance_accepted``, ``maintenance_refused_<reason>``."""
        with self._lock:
            return {("maintenance_accepted" if reason == "accepted" else f"maintenance_refused_{reason}"): n
                    for reason, n in self.counts.items()}

    def _refuse_after_all(self, joint: int, key: str, why: str) -> None:
        """An accepted declaration the agent could not apply (it does not monitor ``joint``): counted as
        refused (``unknown_joint``), not accepted, and it does not use up the joint's rate limit."""
        with self._lock:
            self.counts["accepted"] -= 1
            self.counts["unknown_joint"] += 1
            times = self._accepted_at.get(joint)
            if times:
                times.pop()
                if not times:
                    del self._accepted_at[joint]
        self.log.warning("maintenance declaration on %r refused (%s)", key, why)

    # -- internals ---------------------------------------------------------------------------------

    def _rate_limited(self, joint: int, now: float) -> bool:
        times = self._accepted_at.get(joint)
        if times is None:
            return False
        while times and now - times[0] >= self.window_s:
            times.popleft()
        if not times:
            del self._accepted_at[joint]
            return False
        return len(times) >= self.max_per_joint

    def _log_budget(self, reason: str, joint: int | None, now: float) -> int | None:
        """Number of earlier lines suppressed if this one may be logged now, else None (and count it)."""
        if reason == "accepted":
            return 0
        slot = (reason, joint)
        last = self._last_log.get(slot)
        if last is not None and now - last[0] < self.log_interval_s:
            self._last_log[slot] = (last[0], last[1] + 1)
            return None
        if len(self._last_log) > 4096:      # bound memory under a flood of distinct keys
            self._last_log.clear()
        self._last_log[slot] = (now, 0)
        return 0 if last is None else last[1]

    def _log_decision(self, reason: str, key: str, joint: int | None, payload: Any, source: str,
                      attachment: Any, suppressed: int) -> None:
        details = (f"key={key!r} source={source} "
                   f"attachment='{_printable(_to_text(attachment), self.payload_chars)}' "
                   f"payload='{_printable(_to_text(payload), self.payload_chars)}'")
        more = (f" ({suppressed} similar refusal(s) not logged in the last {self.log_interval_s:g} s)"
                if suppressed else "")
        if reason == "accepted":
            self.log.warning("maintenance declaration ACCEPTED for joint %d: %s", joint, details)
        elif reason == "disabled":
            self.log.warning("maintenance declaration refused (remote declarations are disabled; enable them "
                             "explicitly or use --maintenance at start): %s%s", details, more)
        elif reason == "unknown_joint":
            self.log.warning("maintenance declaration refused (joint %d: this robot has joints 0 … %d): %s%s",
                             joint, MAX_JOINTS - 1, details, more)
        elif reason == "bad_key":
            self.log.warning("maintenance declaration refused (key is not exactly edge/%s/<joint>/maintenance; "
                             "wildcards are never accepted): %s%s", self.robot, details, more)
        else:
            self.log.warning("maintenance declaration refused for joint %d (more than %d in %g s): %s%s",
                             joint, self.max_per_joint, self.window_s, details, more)
