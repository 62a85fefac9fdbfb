"""How every benchmark tool hands over its result: the Markdown on stdout and in its doc file, and
optionally the raw result as JSON."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any, Callable


def write_report(text: str, out: str | Path, json_path: str | Path | None = None, raw: Any = None,
                 default: Callable[[Any], Any] = str) -> None:
    """Print ``text`` and write it to ``out`` (parents created); ``raw`` to ``json_path`` if given
    (``default`` converts what JSON cannot hold: ``str`` keeps paths readable, ``float`` numpy numbers)."""
    print(text)
    out = Path(out)
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(text)
    if json_path:
        Path(json_path).write_text(json.dumps(raw, indent=1, default=default))
