"""What a record must hold before the historian stores it: the fields its published schema requires
(``edge-monitor schema <kind>``), each declared top-level field of the declared type, and a wall time
(``utc``) that is ISO 8601 UTC between 1970 and :data:`MAX_AHEAD_S` after the record arrived.

The schemas are the ones shipped in :mod:`edge_monitor.schemas`; only their top level is checked here
(``type``, ``const``, ``enum``, ``pattern``, ``minimum``, ``exclusiveMinimum``, ``minItems``, ``maxItems``):
enough that every stored record answers ``edge-monitor schema history`` validly and that a record with
no robot, a date in the year 9999 or ``"open": "yes"`` is refused, not stored. A failed check is a reason
the historian counts (``missing_field``, ``bad_field``, ``utc``, ``utc_ahead``) with a detail.
"""

from __future__ import annotations

import functools
import re
from typing import Any

from edge_monitor.historian.times import EARLIEST_S, seconds_of_utc
from edge_monitor.schemas import KINDS, load_schema

#: How far a record's ``utc`` may be after its arrival [s] (clocks of robots and historian a little apart);
#: a later one would stay "the newest" of its joint or fault for ever.
MAX_AHEAD_S = 86400.0

_TYPES: dict[str, tuple[type, ...]] = {"string": (str,), "integer": (int,), "number": (int, float),
                                       "boolean": (bool,), "object": (dict,), "array": (list,),
                                       "null": (type(None),)}


@functools.lru_cache(maxsize=None)
def _schema(kind: str) -> tuple[tuple[str, ...], dict[str, dict[str, Any]]]:
    """The required fields and the declared top-level properties of ``kind``'s schema."""
    schema = load_schema(kind)
    return tuple(schema.get("required", ())), dict(schema.get("properties", {}))


def _is(value: Any, name: str) -> bool:
    if isinstance(value, bool) and name in ("integer", "number"):
        return False
    return isinstance(value, _TYPES.get(name, object))


def _fits(value: Any, rule: dict[str, Any]) -> bool:
    """Whether ``value`` satisfies the top-level keywords of one property's ``rule``."""
    types = rule.get("type")
    if types is not None and not any(_is(value, t) for t in ([types] if isinstance(types, str) else types)):
        return False
    if "const" in rule and not (value == rule["const"] and type(value) is type(rule["const"])):
        return False
    if "enum" in rule and value not in rule["enum"]:
        return False
    if isinstance(value, str) and "pattern" in rule and not re.search(rule["pattern"], value):
        return False
    if _is(value, "number"):
        if "minimum" in rule and not value >= rule["minimum"]:
            return False
        if "exclusiveMinimum" in rule and not value > rule["exclusiveMinimum"]:
            return False
    if isinstance(value, list):
        if len(value) < rule.get("minItems", 0) or len(value) > rule.get("maxItems", len(value)):
            return False
    return True


def field_problem(kind: str, record: dict[str, Any]) -> tuple[str, str] | None:
    """(reason, detail) when ``record`` lacks a field the schema of ``kind`` requires or has a declared
    field of the wrong form; None when it fits (kinds without a published schema are not checked)."""
    if kind not in KINDS:
        return None
    required, properties = _schema(kind)
    for name in required:
        if name not in record:
            return "missing_field", name
    for name, rule in properties.items():
        if name in record and not _fits(record[name], rule):
            return "bad_field", f"{name}={str(record[name])[:40]}"
    return None


def utc_problem(utc: Any, received: float) -> tuple[str, str] | None:
    """(reason, detail) when a record's ``utc`` is neither null nor an ISO 8601 UTC time from 1970 until
    :data:`MAX_AHEAD_S` after ``received`` (the arrival time, Unix s); None when it is fine."""
    if utc is None:
        return None
    seconds = seconds_of_utc(utc)
    if seconds is None or seconds < EARLIEST_S:
        return "utc", str(utc)[:40]
    if seconds > received + MAX_AHEAD_S:
        return "utc_ahead", f"{str(utc)[:40]} is more than {MAX_AHEAD_S:g} s after its arrival"
    return None
