"""The live agent's calibration worker: a real process where the system allows one, a background thread
where it does not (no /dev/shm, as in minimal containers or an initramfs), the same threshold either way."""

from __future__ import annotations

import concurrent.futures
import logging
import time

import numpy as np
import pytest

from edge_monitor.stats.calibration import CalibrationBudget, CalibrationJob
from edge_monitor.stats.calibrators import ProcessCalibrator

pytestmark = pytest.mark.timeout(120)


def _job() -> CalibrationJob:
    nominal = tuple((float(v),) for v in np.random.default_rng(0).normal(size=60))
    return CalibrationJob(nominal, "gauss", 20, 50.0, 0.6, 1.0, "recursive", CalibrationBudget(draws=16, max_steps=600),
                          "increase", 0.5, 3.0)


def _wait(calibrator: ProcessCalibrator):
    pending = calibrator.submit(_job())
    deadline = time.monotonic() + 90
    while (result := pending.result()) is None and time.monotonic() < deadline:
        time.sleep(0.05)
    calibrator.close()
    return result


def test_worker_process_and_thread_fallback_give_the_same_threshold(monkeypatch, caplog) -> None:
    in_process = _wait(ProcessCalibrator())

    def no_semaphores(*args, **kwargs):
        raise FileNotFoundError(2, "No such file or directory")   # what SemLock raises without /dev/shm

    monkeypatch.setattr(concurrent.futures, "ProcessPoolExecutor", no_semaphores)
    caplog.set_level(logging.WARNING, logger="edge_monitor.stats.calibrators")
    in_thread = _wait(ProcessCalibrator())
    assert "background thread" in caplog.text
    expected = _job().run()
    assert in_process is not None and in_thread is not None
    assert in_process.threshold == in_thread.threshold == expected.threshold
