"""The shipped mappings with the short test cycle of the tests (3 speed levels) and absolute paths."""

from __future__ import annotations

import re
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
SPEEDS = (8.7, 41.7, 133.5)


def mapping(name: str, directory: Path, speeds: tuple[float, ...] = SPEEDS, joints: int = 2) -> Path:
    """``protocol/mappings/<name>.toml`` for ``joints`` joints and ``speeds``, written into ``directory``."""
    text = (ROOT / "protocol" / "mappings" / f"{name}.toml").read_text()
    text = text.replace('"../', f'"{ROOT / "protocol"}/')
    text = re.sub(r"^speeds = \[.*\]", f"speeds = [{', '.join(map(str, speeds))}]", text, flags=re.M)
    cut = text.find(f"[joint.{joints}]")
    path = directory / f"{name}.toml"
    path.write_text(text if cut < 0 else text[:cut])
    return path
