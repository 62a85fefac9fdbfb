"""Acknowledgements over Zenoh: a put on ``edge/<robot>/<joint>/acknowledge`` tells the agent that the
latched alarms of that joint were false; each restarts its statistic on the same nominal and threshold
(docs/DETECTION.md, "Acknowledging an alarm") and an "acknowledged" alarm record follows on
``edge/<robot>/<joint>/alarm``.

The payload is an optional JSON object, at most :data:`MAX_PAYLOAD_BYTES`:
``{"quantities": ["kl_raw"], "by": "alice", "note": "probe knocked the arm"}`` (every field optional;
no ``quantities``: every latched quantity of the joint). :func:`parse_request` validates it; a bad one
is refused and counted by the gate (:mod:`edge_monitor.sinks.control_gate`), which also keeps remote
acknowledgements off by default, takes exact keys only and limits them per joint.
"""

from __future__ import annotations

import json
import unicodedata
from dataclasses import dataclass
from typing import Any, ClassVar

from edge_monitor.features.registry import QUANTITIES
from edge_monitor.sinks.control_gate import RemoteConfig
from edge_monitor.sinks.keys import ACKNOWLEDGE

MAX_PAYLOAD_BYTES = 4096                           # a request is a few names and a short note
MAX_BY_CHARS = 64                                  # who acknowledged
MAX_NOTE_CHARS = 500                               # why
FIELDS = ("quantities", "by", "note")
#: Unicode categories refused in ``by`` and ``note``: control (Cc), surrogate (Cs), format (Cf: bidi
#: overrides, zero-width characters) and line/paragraph separators (Zl, Zp): none may forge or hide a log line.
_UNPRINTABLE = frozenset(("Cc", "Cs", "Cf", "Zl", "Zp"))


@dataclass(frozen=True)
class AcknowledgeConfig(RemoteConfig):
    """Remote acknowledgements over Zenoh (the ``[acknowledge]`` table): ``remote`` off by default; at
    most ``max_per_joint`` accepted per joint in any ``window_s`` seconds (one request may name every
    quantity of the joint; more than a few per ten minutes would keep a real fault's statistic at 0)."""

    max_per_joint: int = 4
    action: ClassVar[str] = ACKNOWLEDGE


@dataclass(frozen=True)
class AcknowledgeRequest:
    """A validated acknowledgement: ``quantities`` (None: every latched one), who and why."""

    quantities: tuple[str, ...] | None = None
    by: str | None = None
    note: str | None = None

    def to_payload(self) -> bytes:
        """The JSON payload of this request (what ``edge-monitor acknowledge`` puts)."""
        fields = {"quantities": None if self.quantities is None else list(self.quantities),
                  "by": self.by, "note": self.note}
        return json.dumps({k: v for k, v in fields.items() if v is not None}).encode("utf-8")


def parse_request(payload: bytes) -> AcknowledgeRequest:
    """Validate an acknowledgement payload (UTF-8 JSON object, or empty); ``ValueError`` naming the field
    and the fix for anything else. Never raises another exception, whatever the bytes."""
    if len(payload) > MAX_PAYLOAD_BYTES:
        raise ValueError(f"payload of {len(payload)} bytes; at most {MAX_PAYLOAD_BYTES}")
    if not payload.strip():
        return AcknowledgeRequest()
    try:
        data = json.loads(payload.decode("utf-8"))
    except (UnicodeDecodeError, ValueError, RecursionError):
        raise ValueError('payload is not a UTF-8 JSON object such as {"quantities": ["kl_raw"], "by": "name"}') \
            from None
    if not isinstance(data, dict):
        raise ValueError(f"payload must be a JSON object, got {type(data).__name__}")
    unknown = sorted(set(data) - set(FIELDS))
    if unknown:
        raise ValueError(f"unknown field(s) {', '.join(map(repr, unknown))}; known: {', '.join(FIELDS)}")
    return AcknowledgeRequest(_quantities(data.get("quantities")), _text(data, "by", MAX_BY_CHARS),
                              _text(data, "note", MAX_NOTE_CHARS))


def _quantities(value: Any) -> tuple[str, ...] | None:
    if value is None:
        return None
    if not isinstance(value, list) or not value or not all(isinstance(q, str) for q in value):
        raise ValueError("quantities: expected a non-empty list of quantity names (omit it for all)")
    unknown = [q for q in value if q not in QUANTITIES]
    if unknown:
        shown = ", ".join(repr(q[:40]) for q in unknown[:3])
        raise ValueError(f"quantities: unknown {shown}; known: {', '.join(QUANTITIES)}")
    return tuple(dict.fromkeys(value))


def _text(data: dict[str, Any], name: str, limit: int) -> str | None:
    value = data.get(name)
    if value is None:
        return None
    if not isinstance(value, str) or not 0 < len(value) <= limit:
        raise ValueError(f"{name}: expected a string of 1 … {limit} characters")
    if any(unicodedata.category(c) in _UNPRINTABLE for c in value):
        raise ValueError(f"{name}: control characters are not allowed (nor line or paragraph separators such as "
                         "U+2028, U+2029, nor invisible format characters)")
    return value
