"""The live loop survives a transient receive error, stops (and says why) when the link keeps failing."""

from __future__ import annotations

import threading
import time

import can

from edge_monitor.config import AgentConfig
from edge_monitor.pipeline.agent import Agent
from edge_monitor.pipeline.live import LiveRunner
from edge_monitor.sources.frame_source import LiveSource
from protocol import frames as fr


class FlakyBus(can.BusABC):
    """Delivers MotorState frames; raises on chosen recv calls (or always, after ``fail_from``)."""

    def __init__(self, fail_at=(5,), fail_from=None, **kwargs):
        super().__init__(channel="flaky", **kwargs)
        self.calls = 0
        self.fail_at, self.fail_from = set(fail_at), fail_from

    def _recv_internal(self, timeout):
        self.calls += 1
        if self.calls in self.fail_at or (self.fail_from is not None and self.calls >= self.fail_from):
            raise can.CanOperationError("transient read error")
        tick = self.calls % 256
        data = fr.encode_motor_state(0, tick, 0.1, 10.0, 0.0)
        return can.Message(arbitration_id=fr.MOTOR_STATE_BASE_ID, data=data, is_extended_id=False), False

    def send(self, msg, timeout=None):
        pass


def run_until(runner: LiveRunner, predicate, timeout=20.0) -> None:
    thread = threading.Thread(target=runner.run, daemon=True)
    thread.start()
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline and not predicate() and thread.is_alive():
        time.sleep(0.05)
    runner.stop_event.set()
    thread.join(timeout=10)
    assert not thread.is_alive()


def test_a_transient_receive_error_is_counted_and_monitoring_goes_on():
    bus = FlakyBus(fail_at=(5,))
    runner = LiveRunner(Agent(AgentConfig()), LiveSource(bus, maxsize=1000), status_interval_s=0.2)
    run_until(runner, lambda: runner.agent.ingest.c.frames_total >= 500)
    bus.shutdown()
    assert runner.agent.ingest.c.frames_total >= 500
    assert runner.source.listener.bus_errors == 1
    assert runner.link_failure is None


def test_a_link_that_keeps_failing_stops_the_loop_with_a_reason():
    bus = FlakyBus(fail_from=50)
    source = LiveSource(bus, maxsize=1000)
    source.max_consecutive_errors = 100
    runner = LiveRunner(Agent(AgentConfig()), source, status_interval_s=0.2)
    run_until(runner, lambda: runner.link_failure is not None)
    bus.shutdown()
    assert runner.link_failure and "in a row" in runner.link_failure
