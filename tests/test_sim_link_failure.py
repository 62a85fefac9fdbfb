"""`sim-controller run` on a link that goes away mid-run (the slcan hub or the pty's reader ends): it stops at
once with one message naming the link, its truth file closed, instead of a warning per frame for the rest of
the run and a traceback from closing the dead bus (found 2026-11-30). A tiny --speedup still honours a stop."""

from __future__ import annotations

import json
import threading

import can
import pytest

import sim_controller.output as output
from protocol.links import LinkError
from sim_controller.config import SimConfig


class DeadBus:
    """A bus whose other end is gone: every send fails, and so does closing it."""

    def __init__(self) -> None:
        self.sends = 0

    def send(self, _message: can.Message, timeout: float | None = None) -> None:
        self.sends += 1
        raise can.CanOperationError("Could not write to serial device")

    def shutdown(self) -> None:
        raise can.CanOperationError("Could not write to serial device")


def test_a_link_that_is_gone_ends_the_run_with_one_message(monkeypatch, tmp_path, caplog):
    bus = DeadBus()
    monkeypatch.setattr(output, "open_bus", lambda link, **kw: bus)
    truth = tmp_path / "truth.jsonl"
    with pytest.raises(LinkError, match="slcan:gone.*100 frames in a row"):
        output.run(SimConfig(joints=1, cycles=3), "slcan:gone", speedup=None, truth_path=truth)
    assert bus.sends == output.MAX_FAILED_IN_ROW
    assert len([r for r in caplog.records if "send failed" in r.getMessage()]) == 1
    summary = json.loads(truth.read_text().splitlines()[-1])          # the truth file is closed with its summary
    assert summary["frames_sent"] == 0


def test_a_tiny_speedup_still_stops_when_asked(monkeypatch):
    sent = []

    class SlowBus:
        def send(self, message, timeout=None):
            sent.append(message)

        def shutdown(self):
            pass
    monkeypatch.setattr(output, "open_bus", lambda link, **kw: SlowBus())
    stop = threading.Event()
    threading.Timer(0.5, stop.set).start()
    summary = output.run(SimConfig(joints=1, cycles=1), "virtual:x", speedup=1e-9, stop=stop.is_set)
    assert summary.frames_sent == len(sent) <= 1    # returns at all: before, one sleep of ~10⁶ s per frame
