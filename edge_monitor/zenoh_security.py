"""Zenoh security helpers: TLS/mTLS settings from certificate files, a no-downgrade check, and the gate
that decides whether a remote maintenance declaration is accepted.

Authentication and authorisation belong to the Zenoh router (mutual TLS + access control, see
``edge_monitor/defaults/zenoh/router_acl.json5`` and docs/SECURITY.md). The agent adds two local
defences that do not depend on the router being configured well:

* :class:`MaintenanceGate`: remote maintenance declarations are refused unless explicitly allowed, only
  exact keys ``edge/<this robot>/<joint>/maintenance`` count (no wildcards), each joint accepts at most
  ``max_per_joint`` declarations per ``window_s`` seconds, and every decision is logged with the key,
  the source information Zenoh carries and the (truncated) payload; refusals are counted and their
  logging is rate-limited so that a flood cannot flood the log.
* :func:`check_no_downgrade`: TLS material configured but a plain ``tcp/...`` endpoint is an error, not
  a silent fallback.

Nothing here imports Zenoh at module level: the gate is pure logic, and the settings are plain dicts
that :func:`apply_settings` inserts into a ``zenoh.Config``.
"""

from __future__ import annotations

import json
import logging
import math
import re
import threading
import time
from collections import deque
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable, Mapping

log = logging.getLogger(__name__)

TLS_KEY = "transport/link/tls"
SECURE_PROTOCOLS = ("tls", "quic")                 # Zenoh link protocols that encrypt and authenticate
DEFAULT_MAX_PER_JOINT = 1                          # accepted maintenance declarations per joint ...
DEFAULT_WINDOW_S = 600.0                           # ... per this many seconds
DEFAULT_LOG_INTERVAL_S = 60.0                      # at most one refusal log line per reason and joint per this
PAYLOAD_LOG_CHARS = 200                            # payload characters kept in log lines


class ZenohSecurityError(ValueError):
    """A TLS/ACL setting cannot be used (missing file, plain-text endpoint with TLS configured, ...)."""


# -- TLS settings ------------------------------------------------------------------------------------


@dataclass(frozen=True)
class TlsFiles:
    """PEM files of one Zenoh node.

    ``ca``: certificate of the CA that signed the other side's certificate (clients: the router's;
    router: the clients', needed for mTLS only). ``cert``/``key``: this node's certificate and private
    key (a client presents them for mTLS; a router must have them to listen on ``tls/...``).
    """

    ca: Path | None
    cert: Path | None = None
    key: Path | None = None

    @classmethod
    def from_paths(cls, ca: str | Path | None, cert: str | Path | None = None,
                   key: str | Path | None = None) -> "TlsFiles":
        return cls(*(None if p is None else Path(p) for p in (ca, cert, key)))

    def check(self, need_identity: bool = False, need_ca: bool = False) -> "TlsFiles":
        """Raise :class:`ZenohSecurityError` naming the first missing/unreadable/non-PEM file; returns self.

        ``need_identity``: certificate and key required (router; client of an mTLS router).
        ``need_ca``: CA certificate required (client; mTLS router)."""
        if (self.cert is None) != (self.key is None):
            given, missing = ("certificate", "private key") if self.key is None else ("private key", "certificate")
            raise ZenohSecurityError(f"TLS {given} given without its {missing}; give both (--tls-cert and --tls-key)")
        if need_identity and self.cert is None:
            raise ZenohSecurityError("TLS certificate and private key required (--tls-cert/--tls-key): "
                                     "a router cannot listen on tls/... and an mTLS client cannot connect without them")
        if need_ca and self.ca is None:
            raise ZenohSecurityError("TLS CA certificate required (--tls-ca): it is what the other side's "
                                     "certificate is verified against")
        for role, path in (("CA certificate", self.ca), ("certificate", self.cert), ("private key", self.key)):
            if path is None:
                continue
            if not path.is_file():
                raise ZenohSecurityError(f"TLS {role} file {str(path)!r} does not exist; fix the path")
            try:
                head = path.read_bytes()[:4096]
            except OSError as exc:
                raise ZenohSecurityError(f"TLS {role} file {str(path)!r} is not readable: {exc.strerror}") from exc
            if b"-----BEGIN " not in head:
                raise ZenohSecurityError(f"TLS {role} file {str(path)!r} is not PEM (no '-----BEGIN' line)")
        return self


def client_tls_settings(files: TlsFiles, verify_name: bool = True) -> dict[str, Any]:
    """Zenoh config inserts for a client/peer that connects over ``tls/...``.

    The router's certificate is checked against ``files.ca`` (and its name/IP against the endpoint when
    ``verify_name``); with ``files.cert``/``files.key`` the client presents its certificate (mTLS),
    which is how the router's access control knows who it is (certificate common name)."""
    files.check(need_ca=True)
    tls: dict[str, Any] = {"root_ca_certificate": str(files.ca), "verify_name_on_connect": bool(verify_name)}
    if files.cert is not None:
        tls.update(connect_certificate=str(files.cert), connect_private_key=str(files.key), enable_mtls=True)
    return {TLS_KEY: tls}


def router_tls_settings(files: TlsFiles, mtls: bool | None = True) -> dict[str, Any]:
    """Zenoh config inserts for a router listening on ``tls/...``; ``mtls``: clients must present a
    certificate signed by ``files.ca`` (required for access control by certificate common name);
    ``None`` leaves ``enable_mtls`` as the config has it (never switches mTLS off behind one's back)."""
    files.check(need_identity=True, need_ca=bool(mtls))
    tls: dict[str, Any] = {"listen_certificate": str(files.cert), "listen_private_key": str(files.key)}
    if mtls is not None:
        tls["enable_mtls"] = bool(mtls)
    if files.ca is not None:
        tls["root_ca_certificate"] = str(files.ca)
    return {TLS_KEY: tls}


def apply_settings(config: Any, settings: Mapping[str, Any]) -> Any:
    """Insert ``settings`` (path → JSON value) into a ``zenoh.Config``; a dict under ``transport/link/tls``
    is merged key by key so that settings from a config file that are not overridden survive."""
    for path, value in settings.items():
        items = ({f"{path}/{k}": v for k, v in value.items()} if path == TLS_KEY and isinstance(value, dict)
                 else {path: value})
        for key, item in items.items():
            try:
                config.insert_json5(key, json.dumps(item))
            except Exception as exc:  # zenoh raises ZError on schema violations
                raise ZenohSecurityError(f"zenoh setting {key}={item!r} rejected: {exc}") from exc
    return config


def config_endpoints(config: Any, which: str) -> list[str]:
    """``listen`` or ``connect`` endpoints of a ``zenoh.Config`` for its mode (mode-dependent values
    ``{router: [...], peer: [...], client: [...]}`` resolved with the config's ``mode``, peer by default)."""
    try:
        value = json.loads(config.get_json(f"{which}/endpoints"))
    except Exception:
        return []
    if isinstance(value, dict):
        try:
            mode = json.loads(config.get_json("mode")) or "peer"
        except Exception:
            mode = "peer"
        value = value.get(mode)
    return list(value or [])


def tls_settings_of(config: Any) -> dict[str, Any]:
    """The ``transport/link/tls`` section of a ``zenoh.Config`` (unset keys omitted)."""
    try:
        section = json.loads(config.get_json(TLS_KEY))
    except Exception:
        return {}
    return {k: v for k, v in (section or {}).items() if v is not None}


def check_no_downgrade(endpoints: list[str], tls: Mapping[str, Any], role: str) -> None:
    """Refuse plain-text endpoints when TLS material is configured, and ``tls/...`` endpoints that lack it.

    ``role``: "listen" (a router needs ``listen_certificate``/``listen_private_key``) or "connect"
    (a client needs ``root_ca_certificate`` to authenticate the router)."""
    needed = ("listen_certificate", "listen_private_key") if role == "listen" else ("root_ca_certificate",)
    has_tls = any(tls.get(k) for k in needed)
    secure = [e for e in endpoints if e.split("/", 1)[0] in SECURE_PROTOCOLS]
    plain = [e for e in endpoints if e not in secure]
    if has_tls and plain:
        raise ZenohSecurityError(f"TLS is configured but {role} endpoint(s) {', '.join(plain)} are plain text; "
                                 f"refusing to downgrade: use tls/HOST:PORT")
    missing = [k for k in needed if not tls.get(k)]
    if secure and missing:
        raise ZenohSecurityError(f"{role} endpoint(s) {', '.join(secure)} need TLS setting(s) "
                                 f"{', '.join(TLS_KEY + '/' + k for k in missing)}; give --tls-* files or set them "
                                 f"in the config")
    for key in needed + ("root_ca_certificate",):
        path = tls.get(key)
        if path and not Path(path).is_file():
            raise ZenohSecurityError(f"{TLS_KEY}/{key} file {path!r} does not exist; fix the path")


# -- maintenance gate --------------------------------------------------------------------------------

_KEY_RE = re.compile(r"^edge/(?P<robot>[^/*$?#]+)/(?P<joint>0|[1-9]\d{0,5})/maintenance$")


@dataclass(frozen=True)
class MaintenanceDecision:
    """Outcome of :meth:`MaintenanceGate.decide`; ``joint`` is None when the key names no joint of this robot."""

    accepted: bool
    joint: int | None
    reason: str          # "accepted" | "disabled" | "bad_key" | "rate_limited"


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
        if not robot or any(c in robot for c in "/*$?#"):
            raise ValueError(f"robot name {robot!r} must be non-empty without '/', '*', '$', '?', '#'")
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
        self.counts = {"accepted": 0, "disabled": 0, "bad_key": 0, "rate_limited": 0}
        self._accepted_at: dict[int, deque[float]] = {}
        self._last_log: dict[tuple[str, int | None], tuple[float, int]] = {}   # → (time, suppressed since)
        self._lock = threading.Lock()

    @property
    def key_expr(self) -> str:
        """What the agent subscribes to: ``edge/<robot>/*/maintenance``."""
        return f"edge/{self.robot}/*/maintenance"

    def decide(self, key: str, payload: Any = None, source: str = "unknown", attachment: Any = None,
               now: float | None = None) -> MaintenanceDecision:
        """Accept or refuse one declaration, count it and log it (key, source, attachment, payload)."""
        now = self.clock() if now is None else float(now)
        match = _KEY_RE.match(key)
        joint = int(match["joint"]) if match and match["robot"] == self.robot else None
        with self._lock:
            if joint is None:
                reason = "bad_key"
            elif not self.allow:
                reason = "disabled"
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
                if decision.accepted:
                    declare(decision.joint)
            except Exception as exc:
                self.log.error("maintenance declaration on %s not applied: %s", getattr(sample, "key_expr", "?"), exc)

        return on_sample

    def stats(self) -> dict[str, int]:
        """Counters for health records: ``maintenance_accepted``, ``maintenance_refused_<reason>``."""
        with self._lock:
            return {("maintenance_accepted" if reason == "accepted" else f"maintenance_refused_{reason}"): n
                    for reason, n in self.counts.items()}

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
        more = f" ({suppressed} similar refusal(s) not logged in the last {self.log_interval_s:g} s)" if suppressed else ""
        if reason == "accepted":
            self.log.warning("maintenance declaration ACCEPTED for joint %d: %s", joint, details)
        elif reason == "disabled":
            self.log.warning("maintenance declaration refused (remote declarations are disabled; enable them "
                             "explicitly or use --maintenance at start): %s%s", details, more)
        elif reason == "bad_key":
            self.log.warning("maintenance declaration refused (key is not exactly edge/%s/<joint>/maintenance; "
                             "wildcards are never accepted): %s%s", self.robot, details, more)
        else:
            self.log.warning("maintenance declaration refused for joint %d (more than %d in %g s): %s%s",
                             joint, self.max_per_joint, self.window_s, details, more)
