"""Frame blocks from a live bus (bounded queue); log files are :mod:`~edge_monitor.sources.log_source`.

The live path follows python-can's Bus/Listener boundary: the listener runs on the Notifier's
receive thread and only enqueues into a bounded queue (a full queue drops and counts the frame);
it never raises into the Notifier. The processing thread takes frames out in blocks.
"""

from __future__ import annotations

import logging
import queue
import threading
import time
from dataclasses import dataclass
from typing import Iterator

import can
import numpy as np
from numpy.typing import NDArray

from protocol.frames import messages_to_arrays

log = logging.getLogger(__name__)

FrameArrays = tuple[NDArray[np.int64], NDArray[np.uint8], NDArray[np.int64], NDArray[np.float64]]


class BoundedQueueListener(can.Listener):
    """Enqueue-only listener: counts drops when the queue is full and errors from the bus."""

    def __init__(self, maxsize: int) -> None:
        self.queue: queue.Queue[can.Message] = queue.Queue(maxsize=maxsize)
        self.dropped = 0
        self.received = 0
        self.bus_errors = 0
        self.consecutive_errors = 0       # errors since the last frame received
        self.last_error: str | None = None

    def on_message_received(self, msg: can.Message) -> None:
        try:
            self.received += 1
            self.consecutive_errors = 0
            self.queue.put_nowait(msg)
        except queue.Full:
            self.dropped += 1
        except Exception:  # never raise into the Notifier thread
            self.dropped += 1

    def on_error(self, exc: Exception) -> None:
        self.bus_errors += 1
        self.consecutive_errors += 1
        self.last_error = repr(exc)
        if self.bus_errors in (1, 10, 100) or self.bus_errors % 10_000 == 0:
            log.error("CAN receive error #%d (counted; logged at 1, 10, 100, every 10000): %r",
                      self.bus_errors, exc)

    def stop(self) -> None:
        pass


@dataclass
class LiveSource:
    """Receives from a bus through a Notifier into a bounded queue; ``blocks()`` yields arrays."""

    bus: can.BusABC
    maxsize: int = 65536
    block_size: int = 4096
    poll_s: float = 0.05
    #: After a block's first frame, wait up to this long for more before handing the block over: one
    #: block per ``batch_s`` instead of one per frame or two. The agent's per-block cost is mostly fixed:
    #: at 3,000 frames/s its processing thread used ≈ 48 % of a core with blocks of a few frames, 11 %
    #: with 20 ms, 5.5 % with 50 ms batches (docs/benchmarks/live.md; since then each joint gathers its
    #: samples itself, ``joint_monitor.SAMPLE_BATCH``, and only the ingest's cost is per block). Adds at
    #: most ``batch_s`` to the latency of a symptom (goal p99 ≤ 100 ms), hence 30 ms.
    batch_s: float = 0.03

    def __post_init__(self) -> None:
        self.listener = BoundedQueueListener(self.maxsize)
        self.notifier = can.Notifier(self.bus, [self.listener], timeout=0.1)

    def blocks(self) -> Iterator[FrameArrays | None]:
        """Yield blocks as frames arrive; ``None`` when idle for ``poll_s`` (lets the caller tick).
        Endless: the caller stops iterating, then calls :meth:`stop`; frames still queued then are the
        caller's to count (``queue_depth``)."""
        q = self.listener.queue
        while True:
            try:
                first = q.get(timeout=self.poll_s)
            except queue.Empty:
                yield None
                continue
            batch = [first]
            deadline = time.monotonic() + self.batch_s
            while len(batch) < self.block_size:
                try:
                    batch.append(q.get_nowait())
                except queue.Empty:
                    wait = deadline - time.monotonic()
                    if wait <= 0:
                        break
                    time.sleep(wait)              # let frames gather (see ``batch_s``), then drain once more
            yield messages_to_arrays(batch)

    #: Receive errors in a row (no frame in between) after which the link counts as failed.
    max_consecutive_errors: int = 1000

    @property
    def notifier_failed(self) -> str | None:
        """Why the receive path is dead, or None. A transient error that the listener handled leaves
        python-can's Notifier running (only ``notifier.exception`` is set): that is counted, not fatal."""
        readers = [t for t in getattr(self.notifier, "_readers", []) if isinstance(t, threading.Thread)]
        if readers and not any(t.is_alive() for t in readers):
            return f"receive thread ended: {getattr(self.notifier, 'exception', None)!r}"
        if self.listener.consecutive_errors >= self.max_consecutive_errors:
            return f"{self.listener.consecutive_errors} receive errors in a row, last {self.listener.last_error}"
        return None

    def malformed_lines(self) -> int:
        """Lines the slcan reader could not parse (0 for other interfaces)."""
        return int(getattr(self.bus, "malformed_lines", 0))

    def queue_depth(self) -> int:
        return self.listener.queue.qsize()

    def stop(self) -> None:
        try:
            self.notifier.stop(timeout=1.0)
        except Exception:  # pragma: no cover - shutdown best effort
            log.debug("notifier stop failed", exc_info=True)
