"""Reading Rerun recordings back in tests (rerun.chunk.RrdReader)."""

from __future__ import annotations

from collections import Counter
from pathlib import Path


def rows_by_entity(path: Path | str) -> Counter:
    """Number of non-static rows per entity path in a recording."""
    from rerun.chunk import RrdReader

    counts: Counter = Counter()
    for chunk in RrdReader(str(path)).stream():
        if not chunk.is_static:
            counts[chunk.entity_path] += chunk.num_rows
    return counts
