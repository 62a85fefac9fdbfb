"""The one test of "a finite number" that every package uses on values it did not make itself (config
files, mappings, timelines, saved states): an int or float, not a bool or a string, whose float value
is finite. An int beyond a float's range (TOML and JSON allow 400 digits) is not, and does not raise."""

from __future__ import annotations

import math
from typing import Any, TypeGuard


def finite_or_none(value: Any) -> float | None:
    """``float(value)`` if that is finite, else None (also for strings, None and ints beyond a float)."""
    try:
        number = float(value)
    except (TypeError, ValueError, OverflowError):          # OverflowError: an int beyond a float's range
        return None
    return number if math.isfinite(number) else None


def is_finite_number(value: Any) -> TypeGuard[float]:
    """Whether ``value`` is an int or float (not a bool, not a string) with a finite float value."""
    return isinstance(value, (int, float)) and not isinstance(value, bool) and finite_or_none(value) is not None


def is_count(value: Any) -> TypeGuard[int]:
    """Whether ``value`` is an int (not a bool) ≥ 0: a count read back from a saved state."""
    return isinstance(value, int) and not isinstance(value, bool) and value >= 0
