"""Where every frame of a soak went (tools/soak/soak.py, docs/RELIABILITY.md).

:class:`PtyLinkTap` is a :class:`protocol.links.PtyObserver` on the agent's end of the pty link: the
bridge tells it every byte queued for the agent's terminal, every byte dropped because no agent had
it open, and, when an agent process dies, the queued bytes it never read. It cuts them into slcan
lines and hands the frames to the :class:`LinkLedger`, which attributes each frame the simulator sent
to an agent life (read by that process) or to a downtime, and keeps per agent life what a correct
agent must have counted after its first ``n`` frames (CRC errors + E2E repeats) and the controller
cycles whose frames it read whole. :class:`CanMonitorTap` does the same from a bus monitor on
SocketCAN, where "read by the agent" is known only from the soak's own timeline.

Simulator runs and agent lives are announced by the soak in stream order (``sim_started``,
``agent_started``); the tap's events are processed in the order they happened (``pump``).
"""

from __future__ import annotations

import collections
import logging
import threading
from dataclasses import dataclass, field
from typing import Any

import can
import numpy as np

from protocol.e2e import E2EReceiver, E2EStatus, usable
from protocol.frames import DecodeErrorKind, FrameKind, decode_block

log = logging.getLogger("soak.link")

Key = tuple[int, int]               # (simulator run, raw cycle number); raw cycle -1: the run's start
FRAME_LINE_LENGTH = 21              # "t" + 3 id digits + dlc + 16 data digits (terminator excluded)


@dataclass(frozen=True)
class Transition:
    """The first usable ControllerStatus of a cycle that an agent life read."""

    index: int                      # frame index within the agent life
    key: Key
    pred: Key | None                # the cycle this life read just before (None: nothing since its start/a gap)
    last_status: Key | None         # the last usable status before it (for the agent's numbering)


@dataclass
class AgentLife:
    """One agent process as the link saw it."""

    index: int
    read: int = 0                   # frames that reached the process (final once ``closed``)
    unread: int = 0                 # frames queued for it that it never read (known at its death)
    closed: bool = False
    faults: bytearray = field(default_factory=bytearray)     # per frame read: CRC error or E2E repeat
    transitions: list[Transition] = field(default_factory=list)
    gaps: list[int] = field(default_factory=list)            # frame indices where the link lost frames
    e2e: E2EReceiver = field(default_factory=E2EReceiver)    # what the agent's fresh receiver does
    pred: Key | None = None
    last_status: Key | None = None

    def faults_in_first(self, n: int) -> int:
        """CRC errors + E2E repeats among its first ``n`` frames (what it counted after them)."""
        return self.faults[:max(n, 0)].count(1)


@dataclass
class SimRun:
    """One simulator process as the link saw it (a perfect receiver of everything it sent)."""

    index: int
    frames: int = 0
    faults: int = 0                 # CRC errors + E2E repeats over all its frames
    last_cycle: int = -1
    e2e: E2EReceiver = field(default_factory=E2EReceiver)


class LinkLedger:
    """Attribution of frames and cycles (see the module docstring)."""

    def __init__(self) -> None:
        self.runs: list[SimRun] = []
        self.lives: list[AgentLife] = []
        self.frames_downtime = 0         # sent while no agent had the link open
        self.frames_overflow = 0         # dropped by the link while an agent had it open
        self.frames_unattributed = 0     # arrived before any simulator run / agent life was announced
        self.undelivered_midlife = 0     # queued, then lost by a write error while the agent lived

    # -- announcements ------------------------------------------------------------------------
    def sim_started(self) -> None:
        """Frames from now on belong to a new simulator run."""
        self.runs.append(SimRun(len(self.runs)))
        life = self.open_life
        if life is not None:
            life.pred = (len(self.runs) - 1, -1)

    def agent_started(self) -> None:
        """Frames read from now on belong to a new agent life."""
        self.lives.append(AgentLife(len(self.lives)))

    def agent_closed(self, unread: int) -> None:
        """The open agent life ended; its last ``unread`` frames never reached it."""
        life = self.open_life
        if life is None:
            log.warning("link: an agent end closed without an announced agent")
            return
        unread = min(unread, life.read)
        life.read -= unread
        life.unread = unread
        del life.faults[life.read:]
        life.closed = True

    @property
    def open_life(self) -> AgentLife | None:
        return self.lives[-1] if self.lives and not self.lives[-1].closed else None

    # -- frames -------------------------------------------------------------------------------
    def frames(self, ids: np.ndarray, data: np.ndarray, fate: str) -> None:
        """Frames in stream order: ``fate`` "read" (queued for the open agent), "closed" (no agent
        had the link open) or "overflow" (the link dropped them while an agent had it open)."""
        if len(ids) == 0:
            return
        if not self.runs:
            self.frames_unattributed += len(ids)
            return
        run = self.runs[-1]
        dec = decode_block(ids, data, np.full(len(ids), 8))
        self._wire(run, ids, dec)
        life = self.open_life
        if fate == "read" and life is not None:
            self._read(life, run, ids, dec)
        elif fate == "overflow":
            self.frames_overflow += len(ids)
            if life is not None:
                life.gaps.append(life.read)
        elif fate == "read":
            self.frames_unattributed += len(ids)
        else:
            self.frames_downtime += len(ids)

    def _wire(self, run: SimRun, ids: np.ndarray, dec: Any) -> None:
        statuses, _ = run.e2e.check_block(ids, dec.counter, dec.valid, np.zeros(len(ids)))
        run.frames += len(ids)
        run.faults += int(_fault_mask(dec, statuses).sum())
        status_rows = dec.valid & (dec.kind == FrameKind.CONTROLLER_STATUS)
        if status_rows.any():
            run.last_cycle = max(run.last_cycle, int(dec.cycle[status_rows].max()))

    def _read(self, life: AgentLife, run: SimRun, ids: np.ndarray, dec: Any) -> None:
        statuses, _ = life.e2e.check_block(ids, dec.counter, dec.valid, np.zeros(len(ids)))
        base = life.read
        life.faults += _fault_mask(dec, statuses).astype(np.uint8).tobytes()
        life.read += len(ids)
        rows = np.flatnonzero(dec.valid & usable(statuses) & (dec.kind == FrameKind.CONTROLLER_STATUS))
        for row in rows:
            key = (run.index, int(dec.cycle[row]))
            if key != life.last_status:
                life.transitions.append(Transition(base + int(row), key, life.pred, life.last_status))
                life.pred = life.last_status = key

    # -- conclusions --------------------------------------------------------------------------
    def complete_cycles(self, processed: list[int]) -> dict[Key, int]:
        """Cycles some agent life read whole — from the status frame that followed the previous cycle
        (or from its run's start) to the first status frame of the next cycle of the same run — and had
        processed that last frame (``processed[i]``: frames life ``i`` reported processed). Value: the
        life that saw it."""
        out: dict[Key, int] = {}
        for life, done in zip(self.lives, processed):
            seen = [t for t in life.transitions if t.index < life.read]
            for t, nxt in zip(seen, seen[1:]):
                whole = (t.pred == (t.key[0], t.key[1] - 1) and nxt.key == (t.key[0], t.key[1] + 1)
                         and nxt.index < done and not any(t.index <= g <= nxt.index for g in life.gaps))
                if whole:
                    out.setdefault(t.key, life.index)
        return out

    def cycles_touched(self) -> set[Key]:
        """Cycles of which some agent life read at least one usable status frame."""
        return {t.key for life in self.lives for t in life.transitions if t.index < life.read}

    def numbering(self) -> dict[int, int]:
        """Per simulator run, the offset the agent adds to the raw cycle number (its cycle numbers go on
        across controller restarts, edge_monitor.sources.ingest); runs whose start no agent saw after
        a status frame of the run before are missing."""
        offsets = {0: 0} if self.runs else {}
        switches = {t.key[0]: t for life in self.lives for t in life.transitions
                    if t.last_status is not None and t.last_status[0] == t.key[0] - 1}
        for run in range(1, len(self.runs)):
            t = switches.get(run)
            if t is None or t.last_status is None or run - 1 not in offsets:
                continue
            # a new simulator process starts its tick at 0: the agent sees the tick go back, a controller
            # restart, and numbers on from the last cycle + 1 (edge_monitor.sources.cycle_numbering)
            offsets[run] = t.last_status[1] + offsets[run - 1] + 1 - t.key[1]
        return offsets

    def current(self) -> Key | None:
        """(run, raw cycle) of the last usable status frame read by the open agent life."""
        life = self.open_life
        return None if life is None else life.last_status

    def transitions_processed(self, processed: int) -> int:
        """Cycle starts the open agent life has processed (after ``processed`` frames)."""
        life = self.open_life
        return 0 if life is None else sum(1 for t in life.transitions if t.index < processed)


def _fault_mask(dec: Any, statuses: np.ndarray) -> np.ndarray:
    """Frames an agent counts as faults: CRC errors (``crc_errors``) and E2E repeats (``repeated``)."""
    return (dec.error == DecodeErrorKind.CRC) | (np.asarray(statuses) == E2EStatus.REPEATED)


def parse_frame_lines(lines: list[bytes]) -> tuple[np.ndarray, np.ndarray, list[int], int]:
    """slcan lines (terminator cut) → (ids, data (n, 8), indices of the frame lines, malformed count).
    Command lines (``O``, ``C``, …) are not frames and not malformed."""
    ids: list[int] = []
    payload: list[bytes] = []
    where: list[int] = []
    malformed = 0
    for i, line in enumerate(lines):
        if line[:1] != b"t":
            continue
        try:
            if len(line) != FRAME_LINE_LENGTH or line[4:5] != b"8":
                raise ValueError(line)
            ids.append(int(line[1:4], 16))
            payload.append(bytes.fromhex(line[5:].decode("ascii")))
            where.append(i)
        except (ValueError, UnicodeDecodeError):
            malformed += 1
    data = np.frombuffer(b"".join(payload), dtype=np.uint8).reshape(-1, 8)
    return np.asarray(ids, dtype=np.int64), data, where, malformed


class _Lines:
    """slcan lines of the byte stream towards the agent's end, whether queued for it or lost: a line
    goes where its terminator went (the simulator's write of a line can reach the bridge in two parts,
    the agent dying in between). ``position``: bytes queued so far (stream positions of ``queued``)."""

    def __init__(self) -> None:
        self.position = 0
        self._partial = b""

    def feed(self, data: bytes, queued: bool) -> tuple[list[bytes], list[int]]:
        """Lines completed by ``data`` and, for queued data, the stream position just after each."""
        parts = (self._partial + data).split(b"\r")
        self._partial = parts.pop()
        ends: list[int] = []
        if queued:
            at = data.find(b"\r")
            while at >= 0:
                ends.append(self.position + at + 1)
                at = data.find(b"\r", at + 1)
            self.position += len(data)
        return parts, ends


class PtyLinkTap:
    """PtyObserver of the agent's end (``end``): events queue up on the bridge thread, :meth:`pump`
    hands them to the ledger in order. ``window``: bytes of queued stream whose frame positions are
    kept (must cover what can wait unread: the pty buffer plus the bridge's ``max_buffer``)."""

    def __init__(self, end: str, ledger: LinkLedger, window: int) -> None:
        self.end = end
        self.ledger = ledger
        self.window = window
        self.closes = 0
        self.malformed = 0
        self._events: collections.deque[tuple[Any, ...]] = collections.deque()
        self._lines = _Lines()
        self._ends: collections.deque[int] = collections.deque()   # stream positions of frames of the open life
        self._forgotten = 0                                         # last position dropped from _ends
        self._unread = 0
        self._lock = threading.Lock()

    # -- PtyObserver (bridge thread) ----------------------------------------------------------
    def queued(self, end: str, data: bytes) -> None:
        if end == self.end:
            self._events.append(("queued", data))

    def lost(self, end: str, data: bytes, reason: str) -> None:
        if end == self.end:
            self._events.append(("lost", data, reason))

    def undelivered(self, end: str, start: int, stop: int) -> None:
        if end == self.end:
            self._events.append(("undelivered", start, stop))

    def closed(self, end: str) -> None:
        if end == self.end:
            self._events.append(("closed",))

    # -- the soak's thread --------------------------------------------------------------------
    def announce(self, what: str) -> None:
        """``sim_started`` or ``agent_started``, in order with the link's events."""
        self._events.append((what,))

    def pump(self) -> None:
        """Hand the events queued so far to the ledger: only those, so that a bridge thread queuing
        faster than the ledger digests cannot keep the caller here (the soak's loop starved for an hour
        that way on a loaded machine)."""
        with self._lock:
            for _ in range(len(self._events)):
                event = self._events.popleft()
                getattr(self, "_on_" + event[0])(*event[1:])

    def _on_sim_started(self) -> None:
        self.ledger.sim_started()

    def _on_agent_started(self) -> None:
        self.ledger.agent_started()

    def _on_queued(self, data: bytes) -> None:
        lines, ends = self._lines.feed(data, queued=True)
        ids, frames, where, malformed = parse_frame_lines(lines)
        self.malformed += malformed
        self._ends.extend(ends[i] for i in where)
        while self._ends and self._ends[0] < self._lines.position - self.window:
            self._forgotten = self._ends.popleft()
        self.ledger.frames(ids, frames, "read")

    def _on_lost(self, data: bytes, reason: str) -> None:
        lines, _ = self._lines.feed(data, queued=False)
        ids, frames, _, malformed = parse_frame_lines(lines)
        self.malformed += malformed
        self.ledger.frames(ids, frames, reason)

    def _on_undelivered(self, start: int, stop: int) -> None:
        if start < self._forgotten:
            log.warning("link: unread tail longer than the tap's window; frame attribution is approximate")
        self._unread += sum(1 for e in self._ends if start < e <= stop)

    def _on_closed(self) -> None:
        self.closes += 1
        self.ledger.agent_closed(self._unread)
        self._unread = self._forgotten = 0
        self._ends.clear()


class CanMonitorTap:
    """A bus monitor on SocketCAN (``link``) standing in for the pty tap: every frame on the bus is
    "read" while the soak says an agent listens (``listening``), else a downtime frame. Frames
    in the dead agent's socket buffer count as read, so the kill split is approximate."""

    def __init__(self, link: str, ledger: LinkLedger) -> None:
        from protocol.links import open_bus
        self.ledger = ledger
        self.listening = False
        self.closes = 0
        self.malformed = 0
        self._events: collections.deque[tuple[Any, ...]] = collections.deque()
        self._bus = open_bus(link)
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._receive, name="can-monitor", daemon=True)
        self._thread.start()

    def _receive(self) -> None:
        while not self._stop.is_set():
            msg = self._bus.recv(timeout=0.2)
            if isinstance(msg, can.Message) and not (msg.is_extended_id or msg.is_error_frame):
                self._events.append(("frame", msg.arbitration_id, bytes(msg.data).ljust(8, b"\0"),
                                     "read" if self.listening else "closed"))

    def announce(self, what: str) -> None:
        self._events.append((what,))

    def agent_down(self) -> None:
        """The agent died: frames from now on are downtime frames."""
        self.listening = False
        self._events.append(("closed",))

    def pump(self) -> None:
        """Hand the events queued so far to the ledger (only those: see PtyLinkTap.pump)."""
        for _ in range(len(self._events)):
            event = self._events.popleft()
            if event[0] == "frame":
                self.ledger.frames(np.asarray([event[1]]), np.frombuffer(event[2][:8], np.uint8).reshape(1, 8),
                                   event[3])
            elif event[0] == "closed":
                self.closes += 1
                self.ledger.agent_closed(0)
            else:
                getattr(self.ledger, event[0])()

    def backlog(self) -> int:
        return 0

    def close(self) -> None:
        self._stop.set()
        self._thread.join(timeout=5.0)
        self._bus.shutdown()
