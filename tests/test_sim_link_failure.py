"""`sim-controller run` on a link that goes away mid-run (the slcan hub or the pty's reader ends): it stops at
once with one message naming the link, its truth file closed, instead of a warning per frame for the rest of
the run and a traceback from closing the dead bus (found 2026-11-30). A tiny --speedup still honours a stop."""

from __future__ import annotations

import json
import threading

import can
import numpy as np
import pytest

import sim_controller.output as output
from protocol.e2e import E2EReceiver, E2EStatus
from protocol.frames import DecodeErrorKind, decode_block
from protocol.links import LinkError
from sim_controller.config import SimConfig
from sim_controller.faults import FaultSpec


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
    assert summary.frames_sent == len(sent)    # returns at all: before, one sleep of ~10⁶ s per frame


class CountingBus:
    """Keeps every frame; asks the run to stop once ``stop_after`` frames went out."""

    def __init__(self, stop_after: int) -> None:
        self.ids: list[int] = []
        self.data: list[bytes] = []
        self.stop_after = stop_after

    def send(self, message: can.Message, timeout: float | None = None) -> None:
        self.ids.append(message.arbitration_id)
        self.data.append(bytes(message.data))

    def shutdown(self) -> None:
        pass

    def stopped(self) -> bool:
        return len(self.ids) >= self.stop_after


@pytest.mark.parametrize("stop_after", [1, 157, 1000])
def test_a_stop_mid_block_still_puts_every_counted_fault_on_the_link(monkeypatch, tmp_path, stop_after):
    """SIGTERM ends a run after the frame block being sent: the rest of the block and the frames the
    injector holds back (delayed less than a frame period here, so the E2E check sees
    every duplicate as a repeat) go out at once, so the summary's corrupted + duplicated frames are all on the
    link (a soak's fault ledger compares the two exactly; found 2026-11-30 when a stop mid-block lost one)."""
    bus = CountingBus(stop_after)
    monkeypatch.setattr(output, "open_bus", lambda link, **kw: bus)
    faults = FaultSpec(corrupt=0.02, duplicate=0.02, delay=0.05, delay_max=0.0005)
    summary = output.run(SimConfig(joints=2, cycles=3, faults=faults, seed=4), "virtual:x", speedup=2.0,
                         stop=bus.stopped)
    ids = np.asarray(bus.ids, dtype=np.int64)
    data = np.frombuffer(b"".join(bus.data), dtype=np.uint8).reshape(-1, 8)
    dec = decode_block(ids, data, np.full(len(ids), 8))
    statuses, _ = E2EReceiver().check_block(ids, dec.counter, dec.valid, np.zeros(len(ids)))
    on_link = int(((dec.error == DecodeErrorKind.CRC) | (statuses == E2EStatus.REPEATED)).sum())
    assert summary.cycles < 3 and summary.frames_sent == len(ids) > stop_after - 1
    assert summary.faults["corrupted"] + summary.faults["duplicated"] == on_link > 0
