"""The live loop: a bus → bounded queue → agent blocks, with periodic health, status line and
state saving, until stopped (signal, duration, cycle count or end of the peer's stream). Whether data
flows (:mod:`~edge_monitor.pipeline.data_flow`) goes into each health record and feeds the systemd
watchdog (:mod:`~edge_monitor.pipeline.service_notify`)."""

from __future__ import annotations

import logging
import threading
import time
from dataclasses import dataclass, field
from typing import Any, Callable

from edge_monitor.pipeline.agent import Agent
from edge_monitor.pipeline.data_flow import DataFlow
from edge_monitor.pipeline.service_notify import ServiceNotifier
from edge_monitor.records import Health
from edge_monitor.sources.frame_source import LiveSource

log = logging.getLogger(__name__)
status_log = logging.getLogger("edge_monitor.status")


@dataclass
class LiveRunner:
    """Drives an :class:`Agent` from a :class:`LiveSource`."""

    agent: Agent
    source: LiveSource
    status_interval_s: float = 10.0
    extra_counters: Callable[[], dict[str, Any]] | None = None     # e.g. the outputs' counters, for health
    data_timeout_s: float = 60.0       # no sample for this long: data_flowing false, the watchdog starves
    notifier: ServiceNotifier = field(default_factory=ServiceNotifier)
    stop_event: threading.Event = field(default_factory=threading.Event)
    processing_errors: int = 0
    discarded_at_stop: int = 0
    link_failure: str | None = None
    #: Why :meth:`run` returned: "link_failure", "duration", "max_cycles", "idle", "stopped" (stop_event) or "end".
    stop_reason: str | None = None

    def __post_init__(self) -> None:
        self.flow = DataFlow(self.data_timeout_s, time.monotonic())
        self._was_flowing = True

    def link_counters(self, new_interval: bool = False) -> dict[str, Any]:
        """The live loop's own counters (receive queue, bus, processing, data flow), added to the agent's
        health (``new_interval``: the data-flow counts start again after this record)."""
        listener = self.source.listener
        counters = {"time": time.time(), "queue_depth": self.source.queue_depth(),
                    "queue_dropped": listener.dropped, "bus_errors": listener.bus_errors,
                    "processing_errors": self.processing_errors, "malformed_lines": self.source.malformed_lines(),
                    "link_failure": self.link_failure, "discarded_at_stop": self.discarded_at_stop}
        counters.update(self.flow.interval(time.monotonic(), reset=new_interval))
        if self.extra_counters is not None:
            counters.update(self.extra_counters())
        return counters

    def health(self) -> Health:
        return self.agent.health(self.link_counters())

    def report(self) -> None:
        """A status line and a health record now (e.g. after the last cycle was closed at the end)."""
        self._tick()

    def _tick(self) -> None:
        self.agent.poll(time.time())        # counts NO_NEW_DATA per identifier in the E2E statistics
        h = self.agent.publish_health(self.link_counters(new_interval=True)).counters
        if h["data_flowing"] != self._was_flowing:        # said once per change, not every status interval
            self._was_flowing = h["data_flowing"]
            if not h["data_flowing"]:
                log.warning("no data: no sample for more than %g s (data_timeout_s); %d frames in the last %.0f s: "
                            "is the controller on and the CAN link up?", self.data_timeout_s,
                            h["data_flow"]["frames"], h["data_flow"]["interval_s"])
            else:
                log.warning("data flowing again")
        # out of sequence: a counter jump beyond max_delta, frames lost in a number the alive counter cannot tell
        status_log.info("status: %d frames (%.0f/s), ok %d, crc %d, lost %d, out of sequence %d, queue %d "
                        "(dropped %d), cycles %d, symptoms %d, alarms %d", h["frames_total"], h["frames_per_second"],
                        h["frames_ok"], h["crc_errors"], h["counter_lost"], h["wrong_sequence"], h["queue_depth"],
                        h["queue_dropped"], h["cycles"], h["symptoms"], h["alarms"])

    def run(self, duration_s: float | None = None, max_cycles: int | None = None,
            idle_stop_s: float | None = None) -> None:
        """Process until stopped. ``idle_stop_s``: stop after that long without frames once some arrived."""
        start = time.monotonic()
        next_status = start + self.status_interval_s
        last_frame = start
        seen_any = False
        self.stop_reason = "end"
        self.notifier.ready(f"monitoring, no frame yet (data_timeout_s {self.data_timeout_s:g})")
        try:
            for block in self.source.blocks():
                now = time.monotonic()
                if block is not None:
                    seen_any = True
                    last_frame = now
                    self._process(block, now)
                self._feed_watchdog(now)
                if now >= next_status:
                    self._tick()
                    next_status = now + self.status_interval_s
                failure = self.source.notifier_failed
                if failure is not None:
                    self.link_failure, self.stop_reason = failure, "link_failure"
                    log.error("CAN link failed (%s); stopping", failure)
                    break
                if duration_s is not None and now - start >= duration_s:
                    self.stop_reason = "duration"
                    break
                if max_cycles is not None and self.agent.stats.cycles >= max_cycles:
                    self.stop_reason = "max_cycles"
                    break
                if idle_stop_s is not None and seen_any and now - last_frame >= idle_stop_s:
                    log.info("no frames for %.1f s: end of stream", idle_stop_s)
                    self.stop_reason = "idle"
                    break
                if self.stop_event.is_set():
                    self.stop_reason = "stopped"
                    break
        finally:
            self.notifier.stopping()
            self.source.stop()
            self.discarded_at_stop = self.source.queue_depth()
            if self.discarded_at_stop:
                log.warning("%d frames still queued at stop were not processed (counted)", self.discarded_at_stop)
            self._tick()

    def wait_drained(self, quiet_s: float, limit_s: float = 60.0, poll_s: float = 0.1) -> bool:
        """After the sender has finished (called from another thread while :meth:`run` goes on): wait
        until every received frame is processed and none has arrived for ``quiet_s``; False if
        ``limit_s`` passed first."""
        deadline = time.monotonic() + limit_s
        listener = self.source.listener
        last, last_change = -1, time.monotonic()
        while time.monotonic() < deadline:
            received = listener.received
            if received != last:
                last, last_change = received, time.monotonic()
            elif (time.monotonic() - last_change >= quiet_s and self.source.queue_depth() == 0
                  and self.agent.frames_total >= received):
                return True
            time.sleep(poll_s)
        return False

    def _feed_watchdog(self, now: float) -> None:
        flowing = self.flow.flowing(now)
        quiet = now - (self.flow.last_sample if self.flow.last_sample is not None else self.flow.started)
        self.notifier.watchdog(now, flowing, "monitoring: data flowing" if flowing else
                               f"NO DATA: no sample for {quiet:.0f} s")

    def _process(self, block, now: float) -> None:
        """One block through the agent (its frames and samples counted for the data flow); an unexpected
        error is logged and counted, never fatal."""
        cycles_before = self.agent.stats.cycles
        try:
            with self.agent.lock:
                ingested = self.agent.ingest.update(*block)
                self.flow.add(now, len(block[0]), ingested)
                self.agent.update_ingested(ingested)
        except Exception:
            self.processing_errors += 1
            if self.processing_errors in (1, 10, 100) or self.processing_errors % 1000 == 0:
                log.exception("processing a block of %d frames failed (#%d, counted; monitoring goes on)",
                              len(block[0]), self.processing_errors)
        if self.agent.stats.cycles != cycles_before:
            self._save_state()

    def _save_state(self) -> None:
        try:
            self.agent.save_state()
        except Exception as exc:
            log.error("saving agent state failed (%s); monitoring continues", exc)
