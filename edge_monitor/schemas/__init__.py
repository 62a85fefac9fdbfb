"""JSON Schemas (draft 2020-12) of every record the agent publishes and of the commands' summaries.

One file per kind: ``symptom``, ``alarm``, ``advisory``, ``friction``, ``health``, ``state`` (the state queryable's
reply), ``summary`` (``run/replay/demo --json``), and the historian's answers ``history`` and ``fleet``
(``edge/history/**``, ``edge-monitor history``). A consumer in any language needs only these
(``edge-monitor schema KIND`` prints one). Fields are only ever added within a schema version, so the
schemas allow fields they do not name.
"""

from __future__ import annotations

import json
from importlib import resources
from typing import Any

#: The kinds of record with a schema; the Zenoh key's last segment names the published ones.
KINDS = ("symptom", "alarm", "advisory", "friction", "health", "state", "summary", "history", "fleet")


def schema_text(kind: str) -> str:
    """The schema of ``kind`` as shipped (JSON text); ValueError naming the kinds for any other."""
    if kind not in KINDS:
        raise ValueError(f"no schema for {kind!r}; choose one of {', '.join(KINDS)}")
    return resources.files(__name__).joinpath(f"{kind}.schema.json").read_text(encoding="utf-8")


def load_schema(kind: str) -> dict[str, Any]:
    """The schema of ``kind`` as a dict."""
    return json.loads(schema_text(kind))
