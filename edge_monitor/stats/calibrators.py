"""Where threshold calibrations run: at once in the calling thread (replay, studies) or in a worker
process (a live agent keeps taking frames meanwhile). A :class:`Pending` gives the result when done."""

from __future__ import annotations

import logging
from typing import Any

from edge_monitor.stats.calibration import Calibration, CalibrationError, CalibrationJob
from edge_monitor.stats.densities import DensityError

log = logging.getLogger(__name__)


def exit_with_parent() -> None:
    """In a worker process: end it when the process that started it is gone. A pool's worker waits for
    work for ever, so a parent killed with SIGKILL (no clean-up) would leave it behind, holding its
    memory; a daemon thread waits on the parent's sentinel and exits the worker then."""
    import multiprocessing
    import os
    import threading

    parent = multiprocessing.parent_process()
    if parent is None:
        return

    def watch() -> None:
        parent.join()               # returns when the parent's end of its sentinel pipe closes
        os._exit(0)                 # nothing of the worker's is worth keeping: its results have no reader
    threading.Thread(target=watch, name="exit-with-parent", daemon=True).start()


class Pending:
    """A calibration under way: :meth:`result` is None until it is done."""

    def result(self) -> Calibration | None:
        raise NotImplementedError


class Done(Pending):
    """A finished calibration, or the error it ended with (raised by :meth:`result`, as a future does)."""

    def __init__(self, calibration: Calibration | None = None, error: Exception | None = None) -> None:
        self._calibration, self._error = calibration, error

    def result(self) -> Calibration | None:
        if self._error is not None:
            raise self._error
        return self._calibration


class InlineCalibrator:
    """Calibrates at once, in the calling thread (replay and studies: deterministic and simple)."""

    def submit(self, job: CalibrationJob) -> Pending:
        try:
            return Done(job.run())
        except (CalibrationError, DensityError, ValueError) as exc:   # reported where the result is read
            return Done(error=exc)

    def close(self) -> None:
        """Nothing to release."""


class _FuturePending(Pending):
    def __init__(self, future: Any) -> None:
        self._future = future

    def result(self) -> Calibration | None:
        return self._future.result() if self._future.done() else None


class ProcessCalibrator:
    """Calibrates in one worker process, so a live agent keeps taking frames while detectors calibrate
    (a calibration costs seconds of CPU; all detectors of a robot finish learning at about the same
    cycle). Results arrive a few cycles later; the detector decides with them from then on."""

    def __init__(self) -> None:
        import concurrent.futures
        import multiprocessing

        self._pool: concurrent.futures.Executor
        try:
            self._pool = concurrent.futures.ProcessPoolExecutor(
                max_workers=1, mp_context=multiprocessing.get_context("spawn"), initializer=exit_with_parent)
        except OSError as exc:       # e.g. no /dev/shm (minimal containers, initramfs): no semaphores
            log.warning("calibration worker process unavailable (%s); calibrating in a background thread "
                        "instead (frames are still taken, the numerics share the CPU)", exc)
            self._pool = concurrent.futures.ThreadPoolExecutor(max_workers=1, thread_name_prefix="calibration")

    def submit(self, job: CalibrationJob) -> Pending:
        return _FuturePending(self._pool.submit(job.run))

    def close(self) -> None:
        self._pool.shutdown(wait=False, cancel_futures=True)
