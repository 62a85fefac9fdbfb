"""tools/soak.py as a user runs it: simulator with link faults → live agent; every fault reconciled."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest

pytestmark = pytest.mark.slow
SOAK = Path(__file__).resolve().parent.parent / "tools" / "soak.py"


@pytest.mark.parametrize("faults", [
    "drop=0.001,corrupt=0.001,duplicate=0.0005,reorder=0.0005",
    "drop=0.001,corrupt=0.001,duplicate=0.0005,reorder=0.0005,delay=0.001,silence=1e-4,restart=0.3,stuck=1e-4",
])
def test_soak_reconciles_every_injected_fault(faults: str):
    proc = subprocess.run([sys.executable, str(SOAK), "--cycles", "2", "--joints", "2", "--faults", faults, "--json"],
                          capture_output=True, text=True, timeout=600)
    report = json.loads(proc.stdout)
    assert proc.returncode == 0 and report["ok"], proc.stdout + proc.stderr[-2000:]
    assert report["faults"]["corrupted"] > 0 and report["faults"]["dropped"] > 0
    assert report["queue_dropped"] == 0
