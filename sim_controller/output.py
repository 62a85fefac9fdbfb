"""Outputs of a simulation: a python-can log file (``record``) or a live bus (``run``), plus truth.

``record`` writes as fast as possible with python-can's writer for the file suffix (``.blf``,
``.log`` candump, ``.asc``, …; block writers in ``log_writers``); timestamps are controller time; with
``progress`` a bar over the cycles shows on stderr when it is a terminal. ``run`` paces the
frames to wall time (``speedup`` × real time, ``None`` = as fast as the link takes them) and sends
them on a bus opened with ``protocol.links.open_bus``; timestamps are wall time. A plant stop of the
timeline (no frames for hours of controller time) is a pause of its length / ``speedup``, cut to
``max_pause`` seconds with a warning when longer.

Ground truth (``truth_path``, JSONL): one record per joint per cycle, written as cycles complete,
then a last line ``{"faults": {...}, "frames_sent": N, "send_errors": E}`` (E: sends that raised; a
serial write that timed out may still have put its frame on the link). The per-joint parameters actually used go
to a sidecar ``<truth stem>.params.json``.
"""

from __future__ import annotations

import json
import logging
import time
from dataclasses import dataclass
from pathlib import Path
from typing import IO, Any, Callable

import can

from protocol.console import deferred_interrupts, progress_bar
from protocol.links import LinkError, open_bus
from sim_controller.config import SimConfig
from sim_controller.controller import Controller
from sim_controller.log_writers import block_messages, open_block_writer

log = logging.getLogger(__name__)

#: Seconds of wall time between progress log lines (INFO, ``-v``; ``record`` logs them only without a bar).
STATUS_INTERVAL_S = 10.0
#: Frames due less than this far in the future are sent at once (bounded sleep overhead) [s].
PACING_SLACK_S = 1e-3
#: A sender this far behind its schedule (the process was stopped, or starved of CPU) moves the schedule
#: on instead of catching up in a burst: a frozen controller resumes at its pace [s].
MAX_LAG_S = 1.0
#: Longest wall-clock pause of a plant stop in ``run`` unless told otherwise (``--max-pause``) [s]: long
#: enough for a receiver's timeouts and "no data" handling to show, short enough for a live session.
DEFAULT_MAX_PAUSE_S = 600.0
#: Longest single sleep while pacing, so that ``stop()`` is honoured during a long pause [s].
SLEEP_SLICE_S = 0.25
#: Sends failing this many times in a row end ``run``: the link is gone (a closed pty or TCP peer), not busy.
MAX_FAILED_IN_ROW = 100


@dataclass
class RunSummary:
    """What a run produced."""

    frames_sent: int
    send_errors: int
    cycles: int
    simulated_s: float
    wall_s: float
    faults: dict[str, int]

    @property
    def speed_ratio(self) -> float:
        return self.simulated_s / self.wall_s if self.wall_s > 0 else float("inf")

    def to_dict(self) -> dict[str, Any]:
        return {"frames_sent": self.frames_sent, "send_errors": self.send_errors, "cycles": self.cycles,
                "simulated_s": self.simulated_s, "wall_s": self.wall_s, "speed_ratio": self.speed_ratio,
                "faults": self.faults}


def sidecar_path(truth_path: str | Path) -> Path:
    """``truth.jsonl`` → ``truth.params.json``."""
    p = Path(truth_path)
    return p.with_name(p.stem + ".params.json")


class _TruthWriter:
    def __init__(self, controller: Controller, path: str | Path | None) -> None:
        self.controller = controller
        self.file: IO[str] | None = None
        if path is not None:
            self.file = open(path, "w", encoding="utf-8")
            sidecar_path(path).write_text(json.dumps(controller.parameters(), indent=1) + "\n")

    def drain(self) -> None:
        records = self.controller.drain_truth()
        if self.file is not None and records:
            self.file.write("".join(json.dumps(r) + "\n" for r in records))

    def close(self, frames_sent: int, send_errors: int = 0) -> None:
        self.drain()
        if self.file is not None:
            summary = self.controller.summary()
            summary["frames_sent"] = frames_sent
            summary["send_errors"] = send_errors      # sends that raised: the frame may still be on the link
            self.file.write(json.dumps(summary) + "\n")
            self.file.close()


class _Progress:
    def __init__(self, controller: Controller, what: str) -> None:
        self.controller, self.what = controller, what
        self.start = self.last = time.monotonic()

    def tick(self) -> None:
        now = time.monotonic()
        if now - self.last >= STATUS_INTERVAL_S:
            self.last = now
            c = self.controller
            log.info("%s: cycle %d/%d, %.0f s simulated in %.0f s (%.1f× real time), %d frames",
                     self.what, c.cycles_done, c.config.cycles, c.simulated_seconds, now - self.start,
                     c.simulated_seconds / max(now - self.start, 1e-9), c.frames_emitted)


def record(config: SimConfig, path: str | Path, truth_path: str | Path | None = None,
           progress: bool = False, encoder: Any = None) -> RunSummary:
    """Simulate ``config`` and write all frames to the log ``path`` (format from the suffix);
    ``progress``: a bar over the cycles on stderr if it is a terminal, else INFO lines every 10 s."""
    controller = Controller(config, encoder)
    writer = open_block_writer(path)
    truth = _TruthWriter(controller, truth_path)
    status = _Progress(controller, f"record {path}")
    start = time.perf_counter()
    sent = 0
    with deferred_interrupts() as interrupt:     # Ctrl-C, SIGTERM: end after the block, never mid-container
        try:
            with progress_bar(config.cycles, f"record {Path(path).name}", enabled=progress, unit="cycle") as bar:
                for block in controller.frames():
                    writer.write_block(block)
                    sent += len(block)
                    truth.drain()
                    bar.update(controller.cycles_done - bar.n)
                    if bar.disable:
                        status.tick()
                    if interrupt.pending is not None:
                        break
        finally:
            writer.stop()
            truth.close(sent)
    if interrupt.pending is not None:
        log.warning("%s: stopped after %d frames (%d complete cycles); the log is readable up to there",
                    path, sent, controller.cycles_done)
        raise interrupt.pending
    wall = time.perf_counter() - start
    return RunSummary(sent, 0, controller.cycles_done, controller.simulated_seconds, wall,
                      dict(controller.injector.counts))


def run(config: SimConfig, link: str | None, *, speedup: float | None = 1.0, truth_path: str | Path | None = None,
        bus_kwargs: dict[str, Any] | None = None, stop: Callable[[], bool] | None = None,
        max_pause: float = DEFAULT_MAX_PAUSE_S, encoder: Any = None) -> RunSummary:
    """Stream the simulation onto a bus, paced at ``speedup`` × real time (``None``: unpaced).

    ``link`` is a link string (``slcan:…``, ``socketcan:…``, ``virtual:…``) or ``None`` for
    python-can's configuration; ``bus_kwargs`` go to ``open_bus``. ``stop()`` returning True ends
    the run after the block being sent (checked per frame and during pauses): the rest of the block and
    the frames the fault injector holds back go out back to back, so every counted fault is on the link.
    A sender more than ``MAX_LAG_S`` behind its schedule goes on at its pace from there (no burst; frames
    are never dropped). A gap in the controller's timestamps (a plant stop) pauses at most ``max_pause``
    seconds of wall time.
    """
    bus = open_bus(link, **(bus_kwargs or {}))
    controller = Controller(config, encoder)
    truth = _TruthWriter(controller, truth_path)
    progress = _Progress(controller, f"run {link}")
    start = time.perf_counter()
    wall0 = time.time()
    t0: float | None = None
    last_t: float | None = None                   # controller time of the last frame sent [s]
    shift = 0.0                                   # schedule moved on after stalls and cut pauses [s]
    sender = _Sender(bus, str(link))
    stopped = stop or (lambda: False)
    try:
        for block in controller.frames():
            first = float(block.timestamps[0])
            if t0 is None:
                t0 = first
            paced = speedup is not None and not stopped()
            if paced and speedup is not None and last_t is not None:
                shift -= _cut_pause(first - last_t, speedup, max_pause, controller.cycles_done)
                paced = _wait_until(start + shift + (first - t0) / speedup, stopped)
            last_t = float(block.timestamps[-1])
            # after a stop, the rest of the block goes out back to back: its faults are counted already
            for message, t in zip(block_messages(block), block.timestamps.tolist()):
                if paced and speedup is not None:
                    delay = start + shift + (t - t0) / speedup - time.perf_counter()
                    if delay < -MAX_LAG_S:
                        shift -= delay
                    elif delay > PACING_SLACK_S:     # ≥ 1 ms steps; frames between go out back to back
                        paced = _wait_until(time.perf_counter() + delay, stopped)
                message.timestamp = wall0 + (time.perf_counter() - start)
                sender.send(message)
            truth.drain()
            progress.tick()
            if stopped():
                _send_held_back(controller, sender, wall0 + (time.perf_counter() - start))
                break
    finally:
        truth.close(sender.sent, sender.errors)
        _shut_down(bus, str(link))
    wall = time.perf_counter() - start
    return RunSummary(sender.sent, sender.errors, controller.cycles_done, controller.simulated_seconds, wall,
                      dict(controller.injector.counts))


class _Sender:
    """Puts frames on the bus, counting those that fail; LinkError once :data:`MAX_FAILED_IN_ROW` fail in a row."""

    def __init__(self, bus: can.BusABC, link: str) -> None:
        self.bus, self.link = bus, link
        self.sent = self.errors = self.in_row = 0

    def send(self, message: can.Message) -> None:
        try:
            self.bus.send(message, timeout=1.0)
        except can.CanError as exc:
            self.errors, self.in_row = self.errors + 1, self.in_row + 1
            if self.errors == 1 or self.errors % 1000 == 0:
                log.warning("send failed on %s (%d so far): %s", self.link, self.errors, exc)
            if self.in_row >= MAX_FAILED_IN_ROW:
                raise LinkError(f"the link {self.link} failed: {self.in_row} frames in a row could not be sent "
                                f"({exc}); is the other end still there?") from None
            return
        self.sent, self.in_row = self.sent + 1, 0


def _send_held_back(controller: Controller, sender: _Sender, timestamp: float) -> None:
    """At a stop: the frames the fault injector still holds back (delayed ones) go out now, so every
    counted fault is on the link."""
    for message in block_messages(controller.flush_link()):
        message.timestamp = timestamp
        sender.send(message)


def _shut_down(bus: can.BusABC, link: str) -> None:
    """Close the bus; a link already gone may refuse that too (said at debug level: its failure was said)."""
    try:
        bus.shutdown()
    except (can.CanError, OSError) as exc:
        log.debug("closing %s: %s", link, exc)


def _cut_pause(gap: float, speedup: float, max_pause: float, cycle: int) -> float:
    """Wall seconds to take off a pause of ``gap`` seconds of controller time at ``speedup`` × real
    time so that it lasts at most ``max_pause`` (0 when it is short enough); says so when it cuts."""
    pause = gap / speedup
    if pause <= max_pause:
        if pause > 1.0:
            log.info("plant stop of %.2f h before cycle %d: pausing %.0f s", gap / 3600.0, cycle, pause)
        return 0.0
    log.warning("plant stop of %.2f h before cycle %d would pause %.0f s at %g× real time: pausing %.0f s "
                "instead (--max-pause); frame timestamps show the shorter pause, controller ticks the whole stop",
                gap / 3600.0, cycle, pause, speedup, max_pause)
    return pause - max_pause


def _wait_until(deadline: float, stopped: Callable[[], bool]) -> bool:
    """Sleep until ``deadline`` (``time.perf_counter`` time) in short slices; False if ``stopped()``."""
    while (left := deadline - time.perf_counter()) > PACING_SLACK_S:
        if stopped():
            return False
        time.sleep(min(left, SLEEP_SLICE_S))
    return True
