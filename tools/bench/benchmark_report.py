"""How every benchmark tool hands over its result: the Markdown on stdout and in its doc file, and
optionally the raw result as JSON; and the best-of-repeats timer they share."""

from __future__ import annotations

import json
import time
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


def best_time(fn: Callable[[], object], repeats: int) -> float:
    """The shortest of ``repeats`` wall-clock timings of ``fn()`` [s] (the least disturbed by the shared host)."""
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
    return min(times)
