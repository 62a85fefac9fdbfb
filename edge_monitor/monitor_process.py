"""The agent's monitoring in a second process, fed ingested blocks: a replay on two cores.

A replay spends about a quarter of its CPU reading the log and ingesting it (inflating the ``.blf``,
decoding, E2E checks, cycle assembly) and the rest after ingest (the joints' monitors: segmentation,
friction extraction, wear, KDE/KL, detectors; the outputs). With ``replay --jobs 2`` the parent does
the first part and hands each :class:`~edge_monitor.sources.samples.IngestBlock` over a bounded queue
to a child (:class:`MonitorProcess`), which runs an :class:`~edge_monitor.pipeline.agent.Agent` on them
with :meth:`~edge_monitor.pipeline.agent.Agent.update_ingested` and owns the outputs (JSONL, Rerun).
The child sees the same blocks in the same order as a one-process replay, so it publishes the same
records (``tests/test_monitor_process.py``); the parent's ingest counters go into its statistics at the
end. A child that fails, or dies, stops the replay with a message, never a hang.
"""

from __future__ import annotations

import logging
import multiprocessing
import queue
import signal
import traceback
from contextlib import ExitStack
from dataclasses import dataclass, field
from types import SimpleNamespace
from typing import Any

from edge_monitor.app import build_app
from edge_monitor.run_failures import output_failures, setup_failure
from edge_monitor.sinks.base import LastSymptomSink
from edge_monitor.sinks.jsonl import JsonlOpenError
from edge_monitor.sources.samples import IngestBlock
from protocol.console import terminate_like_interrupt

log = logging.getLogger(__name__)

#: Ingested blocks the parent may be ahead of the child (each ≈ 130 kB pickled for 4 096 frames).
QUEUE_BLOCKS = 64
#: Seconds between checks that the child is still alive while the parent waits on it.
POLL_S = 1.0


class MonitorProcessError(RuntimeError):
    """The monitoring process failed or died; the message says how."""


@dataclass
class MonitorResult:
    """What the child returns at the end: the run statistics, the last symptom per joint (JSON form),
    what it could not write (:func:`~edge_monitor.run_failures.output_failures`), or the exit code
    and message of an output it could not open."""

    statistics: dict[str, Any] = field(default_factory=dict)
    last: dict[int, dict] = field(default_factory=dict)
    failures: list[str] = field(default_factory=list)
    setup_exit: int | None = None


class IngestTotals:
    """Stands in for the ingest inside the child: it holds the parent's counters, set at the end, so
    the child's health and run statistics report the frames the parent read."""

    def __init__(self) -> None:
        self._counters: dict[str, Any] = {"frames_total": 0}
        self.e2e = _E2ETotals()

    @property
    def c(self) -> SimpleNamespace:
        return SimpleNamespace(frames_total=self._counters.get("frames_total", 0))

    def set(self, counters: dict[str, Any], e2e_stats: dict[str, Any]) -> None:
        self._counters, self.e2e.stats = dict(counters), dict(e2e_stats)

    def counters(self) -> dict[str, Any]:
        return dict(self._counters)

    def update(self, *args: Any) -> IngestBlock:
        raise TypeError("the monitoring process takes ingested blocks only")

    def state_dict(self) -> dict[str, Any]:
        return {}

    def load_state(self, state: dict[str, Any]) -> None:
        """Nothing to restore: the parent ingests."""


class _E2ETotals:
    def __init__(self) -> None:
        self.stats: dict[str, Any] = {"no_new_data": 0}

    def poll(self, now: float) -> None:
        """Replay only: no live supervision."""


class MonitorProcess:
    """The child that monitors: :meth:`update` hands it a block, :meth:`finish` ends the run and returns
    its :class:`MonitorResult`. ``outputs``: the :class:`~edge_monitor.app.Outputs` the child opens;
    ``log_level`` and ``log_format``: its logging, as the parent's."""

    def __init__(self, config: Any, outputs: Any, log_level: int, log_format: str) -> None:
        ctx = multiprocessing.get_context("spawn")          # no inherited threads or sessions
        self._inbox = ctx.Queue(maxsize=QUEUE_BLOCKS)
        self._outbox = ctx.Queue()
        self._process = ctx.Process(target=_serve, name="edge-monitor-monitoring", daemon=True,
                                    args=(config, outputs, log_level, log_format, self._inbox, self._outbox))
        self._process.start()
        self._finished = False
        self.setup: MonitorResult | None = self._wait("ready")

    @property
    def pid(self) -> int | None:
        """The child's process id."""
        return self._process.pid

    def update(self, block: IngestBlock) -> None:
        """Queue one ingested block (blocks while the child is ``QUEUE_BLOCKS`` behind)."""
        while True:
            try:
                self._inbox.put(("block", block), timeout=POLL_S)
                return
            except queue.Full:
                self._check_alive()

    def finish(self, close_open_cycle: bool, counters: dict[str, Any], e2e_stats: dict[str, Any],
               flushed: IngestBlock | None = None) -> MonitorResult:
        """End of the log: the child takes ``flushed`` (a source's last samples), the parent's ingest
        counters, closes the open cycle if asked, closes its outputs and returns its result."""
        while True:
            try:
                self._inbox.put(("finish", close_open_cycle, counters, e2e_stats, flushed), timeout=POLL_S)
                break
            except queue.Full:
                self._check_alive()
        result = self._wait("done")
        assert result is not None
        self._finished = True
        self._process.join(timeout=30)
        return result

    def close(self) -> None:
        """Stop the child if it still runs (an interrupted replay: it closes its outputs on SIGTERM). The
        blocks it did not take are dropped: waiting at exit to hand them to a child that is gone hung the
        replay for ever (found 2026-11-30, Ctrl-C with ``--jobs 2``)."""
        if not self._finished:
            self._inbox.cancel_join_thread()
        if self._process.is_alive():
            self._process.terminate()
            self._process.join(timeout=5)
        if self._process.is_alive():
            log.warning("the monitoring process did not stop within 5 s of SIGTERM; killed")
            self._process.kill()
            self._process.join(timeout=5)

    def _wait(self, kind: str) -> MonitorResult | None:
        while True:
            try:
                message = self._outbox.get(timeout=POLL_S)
            except queue.Empty:
                self._check_alive()
                continue
            if message[0] == "error":
                log.debug("the monitoring process failed:\n%s", message[2])
                raise MonitorProcessError(f"the monitoring process failed ({message[1]}); run again with --jobs 1 "
                                          "to see where, in one process")
            if message[0] == "setup_failed":
                return MonitorResult(setup_exit=message[1])
            if message[0] == kind:
                return message[1]

    def _check_alive(self) -> None:
        if not self._process.is_alive():
            raise MonitorProcessError(f"the monitoring process exited unexpectedly (exit code "
                                      f"{self._process.exitcode}); run again with --jobs 1 to see it in one process")


def _serve(config: Any, outputs: Any, log_level: int, log_format: str, inbox: Any, outbox: Any) -> None:
    """The child: an agent after ingest, on the parent's blocks, until "finish"."""
    logging.basicConfig(level=log_level, format=log_format)
    logging.getLogger().setLevel(log_level)
    signal.signal(signal.SIGINT, signal.SIG_IGN)      # Ctrl-C reaches the whole group: the parent decides
    try:
        with terminate_like_interrupt():            # the parent's SIGTERM: outputs closed on the way out
            outbox.put(_monitor(config, outputs, inbox, outbox))
    except BaseException as exc:      # noqa: BLE001 — reported to the parent, which stops the replay with it
        outbox.put(("error", f"{type(exc).__name__}: {exc}", traceback.format_exc()))


def _monitor(config: Any, outputs: Any, inbox: Any, outbox: Any) -> tuple[str, Any]:
    last = LastSymptomSink()
    with ExitStack() as stack:
        try:
            totals = IngestTotals()
            agent = build_app(config, outputs, stack, None, source=totals).agent
        except (ValueError, JsonlOpenError) as exc:        # as replay reports it, in the child's stderr
            return "setup_failed", setup_failure("replay", exc)
        agent.sinks.append(last)
        outbox.put(("ready", None))
        statistics: dict[str, Any] = {}
        while True:
            message = _next(inbox)
            if message is None:                 # the parent is gone (killed): nothing will come
                log.error("the replay process is gone; the monitoring process stops (outputs closed)")
                break
            if message[0] == "block":
                agent.update_ingested(message[1])
                continue
            _, close_open_cycle, counters, e2e_stats, flushed = message
            if flushed is not None:
                agent.update_ingested(flushed)
            totals.set(counters, e2e_stats)
            agent.finish(close_open_cycle=close_open_cycle)
            statistics = agent.run_statistics()
            break
    return "done", MonitorResult(statistics, last.last, output_failures(agent, None))


def _next(inbox: Any) -> tuple | None:
    """The parent's next message, or None once the parent has died (checked every :data:`POLL_S`)."""
    parent = multiprocessing.parent_process()
    while True:
        try:
            return inbox.get(timeout=POLL_S)
        except queue.Empty:
            if parent is not None and not parent.is_alive():
                return None
