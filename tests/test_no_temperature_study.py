"""tools/studies/no_temperature_study.py: a robot without motor temperature, as the study runs it."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np

TOOLS = Path(__file__).resolve().parent.parent / "tools" / "studies"
sys.path.insert(0, str(TOOLS))

from no_temperature_study import without_temperature  # noqa: E402

from sim_controller.config import SimConfig  # noqa: E402
from sim_controller.cycle_mode import cycle_signals  # noqa: E402


def test_the_study_removes_every_motor_temperature_and_nothing_else() -> None:
    signals = next(iter(cycle_signals(SimConfig(joints=2, cycles=1, seed=3))))
    stripped = without_temperature(signals)
    for before, after in zip(signals.joints, stripped.joints):
        assert np.all(np.isfinite(before.motor_temperature)) and np.all(np.isnan(after.motor_temperature))
        assert np.array_equal(before.torque, after.torque) and np.array_equal(before.load_estimate,
                                                                               after.load_estimate)


def test_the_study_runs_and_reports_per_robot(tmp_path: Path) -> None:
    """A short run (40 cycles: the joints learn their models, then their detectors start learning): the
    JSON names the seed, the target, the monitored detector-cycles per stage, the crossings and each
    joint's held detector-cycles; a status line goes to stderr."""
    out = tmp_path / "study.json"
    run = subprocess.run([sys.executable, str(TOOLS / "no_temperature_study.py"), "--seeds", "5", "--cycles", "40",
                          "--json", str(out)], capture_output=True, text=True, timeout=600)
    assert run.returncode == 0, run.stderr
    assert "seed 5: cycle 0 of 40" in run.stderr and run.stdout.startswith("seed 5: monitored")
    (robot,) = json.loads(out.read_text())
    assert robot["seed"] == 5 and robot["arl0"] == 50_400.0
    assert robot["crossings"] == [] and set(robot["held"]) == {str(j) for j in range(6)}
    assert isinstance(robot["monitored"], dict)
