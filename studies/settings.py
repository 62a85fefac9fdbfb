"""What a study varies, from its command line: robots by seed (``"101-108"``, ``"1,2,5"``) and agent settings
(``TABLE.KEY=VALUE``, the value as JSON) turned into the TOML tables ``edge_monitor.config`` merges over the
shipped defaults."""

from __future__ import annotations

import argparse
import json
from typing import Any

#: Agent settings as ``(dotted key, value)`` pairs, e.g. ``(("decision.allowance", 0.5),)``.
Overrides = tuple[tuple[str, Any], ...]


def parse_seeds(text: str) -> list[int]:
    """``"101-108"`` or ``"1,2,5"`` (or a mix) → seeds."""
    seeds: list[int] = []
    for part in text.split(","):
        low, _, high = part.partition("-")
        seeds.extend(range(int(low), int(high or low) + 1))
    return seeds


def parse_set(text: str) -> tuple[str, Any]:
    """``"TABLE.KEY=VALUE"`` → ``("TABLE.KEY", value)``, the value read as JSON (else kept as text); an
    ``argparse`` type."""
    key, sep, raw = text.partition("=")
    if not sep:
        raise argparse.ArgumentTypeError(f"--set expects TABLE.KEY=VALUE, got {text!r}")
    try:
        value = json.loads(raw)
    except json.JSONDecodeError:
        value = raw
    return key.strip(), value


def settings_from(overrides: Overrides) -> dict[str, Any]:
    """The nested tables of ``overrides`` (``config_from_mapping`` merges them over the shipped defaults)."""
    doc: dict[str, Any] = {}
    for dotted, value in overrides:
        table, _, key = dotted.rpartition(".")
        node = doc
        for part in filter(None, table.split(".")):
            node = node.setdefault(part, {})
        node[key] = value
    return doc
