"""Operator requests over Zenoh, gated: a put on ``edge/<robot>/<joint>/<action>`` (``maintenance``:
relearn the joint; ``acknowledge``: a latched alarm was false) asks the agent to act on that joint.

Authentication belongs to the Zenoh router (mTLS + access control, docs/SECURITY.md); the agent adds a
local defence that does not depend on the router being configured well, :class:`ControlGate`: remote
requests are refused unless explicitly allowed, only exact keys ``edge/<this robot>/<joint>/<action>``
count (no wildcards), a joint the robot cannot have (≥ ``MAX_JOINTS``) or the agent does not monitor
is refused (``unknown_joint``), a payload the action cannot parse is refused, each joint accepts at most
``max_per_joint`` requests per ``window_s`` seconds, and every decision is logged with the key, the
source information Zenoh carries and the (truncated) payload; refusals are counted and their logging is
rate-limited. :class:`RemoteConfig` is the config table of one action.
"""

from __future__ import annotations

import logging
import math
import threading
import time
from collections import deque
from dataclasses import dataclass
from typing import Any, Callable, ClassVar

from edge_monitor.errors import ConfigError, UnknownJointError
from edge_monitor.sinks.keys import check_robot_name, joint_key, parse_key
from protocol.frames import MAX_JOINTS

DEFAULT_LOG_INTERVAL_S = 60.0                      # at most one refusal log line per reason and joint per this
PAYLOAD_LOG_CHARS = 200                            # payload characters kept in log lines


@dataclass(frozen=True)
class RemoteConfig:
    """Remote requests of one action over Zenoh (the ``[<action>]`` table), validated once, here.

    ``remote``: accept requests put on Zenoh at all (off by default); at most ``max_per_joint`` accepted
    per joint in any ``window_s`` seconds.
    """

    remote: bool = False
    max_per_joint: int = 1
    window_s: float = 600.0
    #: The action: the last segment of its Zenoh key and the name of its config table.
    action: ClassVar[str] = "request"

    def __post_init__(self) -> None:
        if not (isinstance(self.max_per_joint, int) and 1 <= self.max_per_joint <= 1000):
            raise ConfigError(f"{self.action}.max_per_joint: must be 1 … 1000, got {self.max_per_joint!r}")
        if not (math.isfinite(self.window_s) and 1.0 <= self.window_s <= 30 * 86400):
            raise ConfigError(f"{self.action}.window_s: must be 1 … 2592000 s, got {self.window_s!r}")


def open_gate(session: Any, robot: str, config: RemoteConfig, apply: Callable[..., Any],
              parse: Callable[[bytes], Any] | None = None) -> tuple["ControlGate", Any]:
    """Subscribe to ``edge/<robot>/*/<config.action>`` through a :class:`ControlGate`; accepted puts call
    ``apply(joint)`` (``apply(joint, request)`` with ``parse``). Returns the gate (its ``stats()`` go into
    health) and the subscriber."""
    gate = ControlGate(robot, config.action, allow=config.remote, max_per_joint=config.max_per_joint,
                       window_s=config.window_s, parse=parse)
    return gate, session.declare_subscriber(gate.key_expr, gate.callback(apply))


@dataclass(frozen=True)
class GateDecision:
    """Outcome of :meth:`ControlGate.decide`; ``joint`` is None when the key names no joint of this
    robot; ``request`` is the parsed payload (gates with a parser), ``problem`` why it did not parse."""

    accepted: bool
    joint: int | None
    reason: str          # "accepted" | "disabled" | "bad_key" | "unknown_joint" | "bad_payload" | "rate_limited"
    request: Any = None
    problem: str = ""


def _printable(text: str, limit: int) -> str:
    shown = text[:limit].encode("unicode_escape").decode("ascii")
    return shown + (f"… ({len(text)} chars)" if len(text) > limit else "")


def payload_bytes(value: Any) -> bytes:
    """A Zenoh payload/attachment (ZBytes, bytes, str, None) as bytes."""
    if value is None:
        return b""
    if hasattr(value, "to_bytes"):
        value = value.to_bytes()
    if isinstance(value, (bytes, bytearray, memoryview)):
        return bytes(value)
    return str(value).encode("utf-8")


def _to_text(value: Any) -> str:
    """Payload/attachment as text for logs; undecodable bytes as escapes."""
    return payload_bytes(value).decode("utf-8", errors="backslashreplace")


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


class ControlGate:
    """Decides whether a remote request (a put on ``edge/<robot>/<joint>/<action>``) is accepted.
    Thread-safe; pure logic (Zenoh samples are read by duck typing).

    ``robot``: this agent's robot name; only exact keys for it count. ``action``: the key's last segment.
    ``allow``: accept remote requests at all (off by default).
    ``max_per_joint`` / ``window_s``: at most that many accepted requests per joint in any sliding
    window of ``window_s`` seconds; the excess is refused and counted.
    ``parse(payload bytes) -> request``: validates the payload (``ValueError``: refused as "bad_payload",
    not counted against the rate limit); without it any payload is accepted as free text.
    A joint ≥ ``MAX_JOINTS`` is refused as "unknown_joint"; so is, after all, an accepted request whose
    action raises ``ValueError`` because the agent does not monitor the joint (:meth:`callback`).
    ``log_interval_s``: per (reason, joint), refusals are logged at most once per interval; the next
    line says how many were not logged. Accepted requests are always logged (to ``logger``, default
    ``edge_monitor.sinks.<action>``).
    ``clock``: monotonic seconds (injectable for tests).
    """

    #: How log lines name a request of each action.
    NOUNS: ClassVar[dict[str, str]] = {"maintenance": "maintenance declaration", "acknowledge": "acknowledgement"}

    def __init__(self, robot: str, action: str, allow: bool = False, max_per_joint: int = 1,
                 window_s: float = 600.0, parse: Callable[[bytes], Any] | None = None,
                 logger: logging.Logger | None = None, log_interval_s: float = DEFAULT_LOG_INTERVAL_S,
                 payload_chars: int = PAYLOAD_LOG_CHARS, clock: Callable[[], float] = time.monotonic) -> None:
        check_robot_name(robot)
        if int(max_per_joint) < 1:
            raise ValueError(f"max_per_joint={max_per_joint} must be >= 1 (use allow=False to refuse all)")
        if not (math.isfinite(window_s) and window_s > 0):
            raise ValueError(f"window_s={window_s} must be a positive number of seconds")
        if not (math.isfinite(log_interval_s) and log_interval_s >= 0):
            raise ValueError(f"log_interval_s={log_interval_s} must be >= 0 seconds")
        self.robot, self.action = robot, action
        self.noun = self.NOUNS.get(action, f"{action} request")
        self.allow = bool(allow)
        self.max_per_joint = int(max_per_joint)
        self.window_s = float(window_s)
        self.parse = parse
        self.log_interval_s = float(log_interval_s)
        self.payload_chars = int(payload_chars)
        self.log = logger or logging.getLogger(f"edge_monitor.sinks.{action}")
        self.clock = clock
        reasons = (("accepted", "disabled", "bad_key", "unknown_joint") + (("bad_payload",) if parse else ())
                   + ("rate_limited",))
        self.counts = dict.fromkeys(reasons, 0)
        self._accepted_at: dict[int, deque[float]] = {}
        self._last_log: dict[tuple[str, int | None], tuple[float, int]] = {}   # → (time, suppressed since)
        self._lock = threading.Lock()

    @property
    def key_expr(self) -> str:
        """What the agent subscribes to: ``edge/<robot>/*/<action>``."""
        return joint_key(self.robot, "*", self.action)

    def decide(self, key: str, payload: Any = None, source: str = "unknown", attachment: Any = None,
               now: float | None = None) -> GateDecision:
        """Accept or refuse one request, count it and log it (key, source, attachment, payload)."""
        now = self.clock() if now is None else float(now)
        parts = parse_key(key)
        joint = parts.joint if parts is not None and parts.robot == self.robot and parts.kind == self.action else None
        request, problem = None, ""
        if joint is not None and joint < MAX_JOINTS and self.allow and self.parse is not None:
            try:
                request = self.parse(payload_bytes(payload))
            except ValueError as exc:
                problem = str(exc) or type(exc).__name__
        with self._lock:
            if joint is None:
                reason = "bad_key"
            elif not self.allow:
                reason = "disabled"
            elif joint >= MAX_JOINTS:
                reason = "unknown_joint"
            elif problem:
                reason = "bad_payload"
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
            details = (f"key={key!r} source={source} "
                       f"attachment='{_printable(_to_text(attachment), self.payload_chars)}' "
                       f"payload='{_printable(_to_text(payload), self.payload_chars)}'")
            self._log_decision(reason, joint, details, _printable(problem, self.payload_chars), suppressed)
        return GateDecision(reason == "accepted", joint, reason, request if reason == "accepted" else None, problem)

    def decide_sample(self, sample: Any, now: float | None = None) -> GateDecision:
        """:meth:`decide` for a ``zenoh.Sample`` (key_expr, payload, attachment, source_info)."""
        return self.decide(str(sample.key_expr), getattr(sample, "payload", None), describe_source(sample),
                           getattr(sample, "attachment", None), now)

    def callback(self, apply: Callable[..., Any]) -> Callable[[Any], None]:
        """A Zenoh subscriber callback: gate each sample, then ``apply(joint)`` when accepted
        (``apply(joint, request)`` for a gate with a parser). An ``apply`` that raises ``ValueError``
        refuses the request after all (:meth:`refuse_after_all`). Never raises into Zenoh's thread; a
        failing ``apply`` is logged with the key."""

        def on_sample(sample: Any) -> None:
            try:
                decision = self.decide_sample(sample)
                if decision.accepted and decision.joint is not None:
                    try:
                        if self.parse is None:
                            apply(decision.joint)
                        else:
                            apply(decision.joint, decision.request)
                    except ValueError as exc:     # e.g. a joint the agent does not monitor
                        self.refuse_after_all(decision.joint, str(getattr(sample, "key_expr", "?")), exc)
            except Exception as exc:
                self.log.error("%s on %s not applied: %s", self.noun, getattr(sample, "key_expr", "?"), exc)

        return on_sample

    def stats(self) -> dict[str, int]:
        """Counters for health records: ``<action>_accepted``, ``<action>_refused_<reason>``."""
        with self._lock:
            return {(f"{self.action}_accepted" if reason == "accepted" else f"{self.action}_refused_{reason}"): n
                    for reason, n in self.counts.items()}

    def refuse_after_all(self, joint: int, key: str, exc: ValueError) -> None:
        """An accepted request the agent could not apply: counted as refused, not accepted, and it gives
        back its slot of the joint's rate limit (nothing was done). ``unknown_joint`` when the agent does
        not monitor the joint (:class:`~edge_monitor.errors.UnknownJointError`, or any ``ValueError`` of
        a gate without a parser), else ``bad_payload`` (e.g. a quantity the joint does not watch)."""
        unknown = isinstance(exc, UnknownJointError) or self.parse is None
        reason = "unknown_joint" if unknown else "bad_payload"
        with self._lock:
            self.counts["accepted"] -= 1
            self.counts[reason] += 1
            times = self._accepted_at.get(joint)
            if times:
                times.pop()
                if not times:
                    del self._accepted_at[joint]
            suppressed = self._log_budget(reason, joint, self.clock())
        if suppressed is not None:
            more = (f" ({suppressed} similar refusal(s) not logged in the last {self.log_interval_s:g} s)"
                    if suppressed else "")
            self.log.warning("%s on %r refused after all (%s)%s", self.noun, key,
                             _printable(str(exc), self.payload_chars), more)

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

    def _log_decision(self, reason: str, joint: int | None, details: str, problem: str, suppressed: int) -> None:
        more = (f" ({suppressed} similar refusal(s) not logged in the last {self.log_interval_s:g} s)"
                if suppressed else "")
        if reason == "accepted":
            self.log.warning("%s ACCEPTED for joint %d: %s", self.noun, joint, details)
        elif reason == "disabled":
            self.log.warning("%s refused (remote %s is disabled on this agent; enable it explicitly: [%s] "
                             "remote = true or run --allow-remote-%s): %s%s", self.noun, self.action, self.action,
                             self.action, details, more)
        elif reason == "bad_key":
            self.log.warning("%s refused (key is not exactly edge/%s/<joint>/%s; wildcards are never accepted): "
                             "%s%s", self.noun, self.robot, self.action, details, more)
        elif reason == "unknown_joint":
            self.log.warning("%s refused (joint %d: this robot has joints 0 … %d): %s%s", self.noun, joint,
                             MAX_JOINTS - 1, details, more)
        elif reason == "bad_payload":
            self.log.warning("%s refused for joint %d (%s): %s%s", self.noun, joint, problem, details, more)
        else:
            self.log.warning("%s refused for joint %d (more than %d in %g s): %s%s",
                             self.noun, joint, self.max_per_joint, self.window_s, details, more)
