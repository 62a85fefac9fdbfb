"""Both commands say which version they are (one version for the simulator, protocol and agent)."""

from __future__ import annotations

import subprocess
import sys
from importlib import metadata

import pytest


@pytest.mark.parametrize("module, prog", [("edge_monitor.cli", "edge-monitor"), ("sim_controller.cli", "sim-controller")])
def test_version_flag_prints_the_installed_version(module: str, prog: str) -> None:
    out = subprocess.run([sys.executable, "-m", module, "--version"], capture_output=True, text=True, timeout=60)
    assert out.returncode == 0, out.stderr
    assert out.stdout.strip() == f"{prog} {metadata.version('joint-wear-monitor')}"
