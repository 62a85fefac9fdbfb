"""Strict JSON for everything the agent writes (state file, JSONL, Zenoh payloads, CLI output):
NaN and ±inf become ``null`` (JSON has no NaN), numpy scalars and arrays become Python values."""

from __future__ import annotations

import json
import math
from typing import Any

import numpy as np

#: Version of every published record (symptom, alarm, friction, health): the "schema" field.
SCHEMA_VERSION = 1


def to_strict(value: Any) -> Any:
    """``value`` with NaN/±inf → None and numpy scalars/arrays → Python types, recursively."""
    if isinstance(value, dict):
        return {str(k): to_strict(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [to_strict(v) for v in value]
    if isinstance(value, np.ndarray):
        return to_strict(value.tolist())
    if isinstance(value, (bool, np.bool_)):
        return bool(value)
    if isinstance(value, (int, np.integer)):
        return int(value)
    if isinstance(value, (float, np.floating)):
        number = float(value)
        return number if math.isfinite(number) else None
    return value


def dumps(value: Any, **kwargs: Any) -> str:
    """Compact strict JSON text of ``value`` (``kwargs`` go to ``json.dumps``, e.g. ``indent``)."""
    kwargs.setdefault("separators", (",", ":"))
    return json.dumps(to_strict(value), allow_nan=False, **kwargs)
