"""The shipped mappings with the short test cycle of the tests (3 speed levels) and absolute paths, and
recordings of the simulator in each profile."""

from __future__ import annotations

import re
import subprocess
import sys
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


def record(directory: Path, name: str, profile: str, *, suffix: str = ".log", speeds: tuple[float, ...] = SPEEDS,
           cycles: int = 4, seed: int = 4, joints: int = 2) -> Path:
    """``sim-controller record`` of ``joints`` joints and ``cycles`` cycles in ``profile`` (native, cia402,
    dbc:MAPPING.toml) to ``directory/name + suffix``."""
    out = directory / f"{name}{suffix}"
    subprocess.run([sys.executable, "-m", "sim_controller.cli", "record", "--out", str(out), "--joints", str(joints),
                    "--cycles", str(cycles), "--seed", str(seed), "--speeds", ",".join(map(str, speeds)),
                    "--profile", profile, "-q"], check=True)
    return out
