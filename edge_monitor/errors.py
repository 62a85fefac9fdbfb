"""Error types shared by every layer of the agent (a leaf module: it imports nothing of the project)."""

from __future__ import annotations


class ConfigError(ValueError):
    """A configuration value is missing, of the wrong type or out of range; the message names the
    field (``section.key``) and what is expected."""


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


def config_changes(saved: dict[str, object], current: dict[str, object]) -> dict[str, tuple[object, object]]:
    """Fields whose values differ between a saved and the current config fingerprint."""
    keys = set(saved) | set(current)
    return {k: (saved.get(k), current.get(k)) for k in keys if saved.get(k) != current.get(k)}
