"""Error types shared by every layer of the agent (a leaf module: it imports nothing of the project)."""

from __future__ import annotations

import json
import re

_BARE_KEY = re.compile(r"[A-Za-z0-9_/.-]+")


class ConfigError(ValueError):
    """A configuration value is missing, of the wrong type or out of range; the message names the
    field (``section.key``) and what is expected."""


class UnknownJointError(ValueError):
    """A request names a joint the agent does not monitor (not configured, or nothing learned for it)."""


class StateError(ValueError):
    """A saved state cannot be used (unreadable, wrong version, another robot, out of bounds)."""


class StateMismatch(StateError):
    """A saved component state was learned with another configuration than the current one.

    ``changes`` maps each changed field to ``(saved, current)``.
    """

    def __init__(self, component: str, changes: dict[str, tuple[object, object]]) -> None:
        self.component = component
        self.changes = changes
        listed = ", ".join(f"{k} {old!r} → {new!r}" for k, (old, new) in sorted(changes.items()))
        super().__init__(f"{component}: configuration changed since the state was saved ({listed})")


def require(ok: bool, field: str, message: str) -> None:
    """Raise :class:`ConfigError` ``"field: message"`` unless ``ok``."""
    if not ok:
        raise ConfigError(f"{field}: {message}")


def check_learned_with(component: str, state: dict[str, object], current: dict[str, object]) -> None:
    """Raise :class:`StateMismatch` unless ``state["config"]`` (the fingerprint a component saved with
    its learned numbers) equals ``current`` (the fingerprint of the config it is restored with)."""
    saved = state.get("config", {})
    changes = config_changes(saved if isinstance(saved, dict) else {}, current)
    if changes:
        raise StateMismatch(component, changes)


def config_changes(saved: dict[str, object], current: dict[str, object]) -> dict[str, tuple[object, object]]:
    """Fields whose values differ between a saved and the current config fingerprint."""
    keys = set(saved) | set(current)
    return {k: (saved.get(k), current.get(k)) for k in keys if saved.get(k) != current.get(k)}


def key_name(key: object) -> str:
    """``key`` for a message: as is when it is a plain name or path, else quoted with escapes, so that a
    hostile key (newlines, control characters) cannot forge or split a log line."""
    text = str(key)
    return text if _BARE_KEY.fullmatch(text) else json.dumps(text)


def shown(value: object, width: int = 40) -> str:
    """``repr(value)`` cut to ``width`` characters, saying so (a 400-digit integer is not a message)."""
    text = repr(value)
    return text if len(text) <= width else f"{text[:width]}… ({len(text)} characters)"
