"""The Rerun installation around the SDK: its ``rerun`` CLI (compacting recordings) and its usage reporting.

Usage reporting. The Rerun viewer and SDK report anonymous usage to the Rerun team unless the user's Rerun analytics
config says otherwise; an edge box should not phone home. Before ``edge-monitor`` opens a recording,
spawns a viewer or runs the ``rerun`` CLI, :func:`usage_reporting_off` writes that config as
``rerun analytics disable`` would (``$XDG_CONFIG_HOME/rerun/analytics.json``, by default
``~/.config/rerun/``; ``~/Library/Application Support/rerun/`` on macOS), keeping any existing id.
``rerun analytics enable`` undoes it until the product starts Rerun again (docs/SECURITY.md).
"""

from __future__ import annotations

import json
import logging
import os
import shutil
import subprocess
import sys
import tempfile
import uuid
from pathlib import Path

log = logging.getLogger(__name__)

_checked: set[Path] = set()


def analytics_config_path() -> Path:
    """Where Rerun reads its analytics config (the ``directories`` crate's config dir of "rerun")."""
    if sys.platform == "darwin":
        return Path.home() / "Library" / "Application Support" / "rerun" / "analytics.json"
    base = os.environ.get("XDG_CONFIG_HOME") or str(Path.home() / ".config")
    return Path(base) / "rerun" / "analytics.json"


def _analytics_data_path() -> Path:
    """Where Rerun keeps usage events not yet sent (a field its config file must name)."""
    if sys.platform == "darwin":
        return Path.home() / "Library" / "Application Support" / "rerun" / "analytics"
    base = os.environ.get("XDG_DATA_HOME") or str(Path.home() / ".local" / "share")
    return Path(base) / "rerun" / "analytics"


def usage_reporting_off() -> bool:
    """Make Rerun's analytics config say disabled; True when it does. Never raises: a config that cannot
    be written is logged with the command that fixes it."""
    path = analytics_config_path()
    if path in _checked:
        return True
    try:
        config = json.loads(path.read_text(encoding="utf-8")) if path.exists() else {}
        if not isinstance(config, dict):
            config = {}
        fields = {"analytics_id", "metadata", "config_file_path", "data_dir_path"}
        if config.get("analytics_enabled") is not False or not fields <= config.keys():
            config.update({"analytics_enabled": False})
            config.setdefault("analytics_id", uuid.uuid4().hex)
            config.setdefault("metadata", {})
            config.setdefault("config_file_path", str(path))           # Rerun rejects a config without them
            config.setdefault("data_dir_path", str(_analytics_data_path()))
            _write_atomically(path, json.dumps(config))
            log.info("Rerun usage reporting turned off in %s (docs/SECURITY.md)", path)
    except (OSError, ValueError) as exc:
        log.warning("could not turn off Rerun's anonymous usage reporting in %s (%s); run `rerun analytics "
                    "disable` as this user", path, exc)
        return False
    _checked.add(path)
    return True


def _write_atomically(path: Path, text: str) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    with tempfile.NamedTemporaryFile("w", dir=path.parent, delete=False, encoding="utf-8") as fh:
        fh.write(text)
    os.replace(fh.name, path)


def rerun_executable() -> str | None:
    """The ``rerun`` CLI of this installation (beside the Python executable), else the one on PATH."""
    return shutil.which("rerun", path=str(Path(sys.executable).parent)) or shutil.which("rerun")


def compact_recording(path: str) -> bool:
    """Rewrite a closed recording with its chunks compacted (``rerun rrd optimize``), in place; True when
    done. Blocks drawn live (a viewer's batching) make many small chunks; a reader loads fewer, larger
    ones faster. Never raises: on failure the recording stays as written and a warning says why."""
    executable = rerun_executable()
    if executable is None or not Path(path).is_file():
        return False
    compacted = f"{path}.compacting"
    try:
        done = subprocess.run([executable, "rrd", "optimize", path, "-o", compacted], capture_output=True,
                              text=True, timeout=600, stdin=subprocess.DEVNULL)
        if done.returncode != 0 or not Path(compacted).is_file():
            last_line = done.stderr.strip().splitlines()[-1:] or [f"exit code {done.returncode}"]
            raise RuntimeError(last_line[0])
        os.replace(compacted, path)
        return True
    except (OSError, RuntimeError, subprocess.TimeoutExpired) as exc:
        log.warning("recording %s left as written: compacting it failed (%s)", path, exc)
        Path(compacted).unlink(missing_ok=True)
        return False
