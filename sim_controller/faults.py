"""Link fault injection on the encoded frame stream, with a counter for every injected fault.

Applied per block, in this order (each step acts on what the previous left):

* ``silence``   per-frame probability of a bus silence starting at that frame; all frames within
                ``silence_time`` are removed (``silences`` periods, ``silenced`` frames)
* ``drop``      per-frame probability of losing the frame (``dropped``)
* ``stuck``     per-MotorState-frame probability that this joint's signal freezes for ``stuck_time``:
                later frames keep their own alive counter but repeat the frozen torque/speed/position
                bytes, with a valid CRC — a fault E2E cannot see (``stuck`` frames, ``stuck_periods``)
* ``corrupt``   per-frame probability of flipping 1–3 distinct random bits of the 8 data bytes
                (``corrupted``); CRC-8H2F detects every such pattern on these frames
* ``duplicate`` per-frame probability of sending the frame twice (``duplicated``)
* ``reorder``   per-frame probability of swapping the frame with the next one (``reordered`` swaps)
* ``delay``     per-frame probability of a delay uniform in (0, ``delay_max``] s; the frame moves
                behind the frames sent meanwhile (``delayed``)

Controller restarts (``restart``, per-cycle probability) are made by the controller itself (tick
and alive counters start again at 0 after ``restart_gap`` s without frames) and counted here as
``restarts``. All randomness comes from the generator passed in (seeded by the controller).
"""

from __future__ import annotations

from dataclasses import dataclass, fields
from typing import Callable

import numpy as np
from numpy.typing import NDArray

#: Keys of ``--faults`` that are probabilities.
RATE_KEYS = ("drop", "corrupt", "duplicate", "reorder", "delay", "silence", "restart", "stuck")
#: Keys of ``--faults`` that are durations [s].
TIME_KEYS = ("delay_max", "silence_time", "stuck_time", "restart_gap")
#: Counter names in the truth summary.
COUNTER_KEYS = ("dropped", "corrupted", "duplicated", "reordered", "delayed", "silenced", "silences",
                "restarts", "stuck", "stuck_periods")
MOTOR_STATE_BASE_ID = 0x100
DUPLICATE_OFFSET_S = 1e-6


class FaultSpecError(ValueError):
    """Invalid ``--faults`` value; the message names the key."""


@dataclass(frozen=True)
class FaultSpec:
    """Fault rates (probabilities per frame; ``restart`` per cycle) and durations [s]."""

    drop: float = 0.0
    corrupt: float = 0.0
    duplicate: float = 0.0
    reorder: float = 0.0
    delay: float = 0.0
    silence: float = 0.0
    restart: float = 0.0
    stuck: float = 0.0
    delay_max: float = 0.02
    silence_time: float = 0.2
    stuck_time: float = 0.5
    restart_gap: float = 0.5

    def __post_init__(self) -> None:
        for key in RATE_KEYS:
            value = getattr(self, key)
            if not (0.0 <= value <= 1.0):
                raise FaultSpecError(f"faults.{key}: probability must be 0 … 1, got {value!r}")
        for key in TIME_KEYS:
            value = getattr(self, key)
            if not (0.0 < value <= 60.0):
                raise FaultSpecError(f"faults.{key}: duration must be in (0, 60] s, got {value!r}")

    @property
    def any_link_fault(self) -> bool:
        return any(getattr(self, k) > 0 for k in RATE_KEYS if k != "restart")

    def to_dict(self) -> dict[str, float]:
        return {f.name: getattr(self, f.name) for f in fields(self)}

    @classmethod
    def parse(cls, text: str) -> "FaultSpec":
        """``drop=0.001,corrupt=0.001,...`` → :class:`FaultSpec` (empty string: no faults)."""
        values: dict[str, float] = {}
        for item in (s.strip() for s in text.split(",")):
            if not item:
                continue
            key, sep, raw = item.partition("=")
            key = key.strip()
            if not sep:
                raise FaultSpecError(f"faults: expected KEY=VALUE, got {item!r}")
            if key not in RATE_KEYS + TIME_KEYS:
                raise FaultSpecError(f"faults: unknown kind {key!r}; known: {', '.join(RATE_KEYS + TIME_KEYS)}")
            try:
                values[key] = float(raw)
            except ValueError:
                raise FaultSpecError(f"faults.{key}: expected a number, got {raw!r}") from None
        return cls(**values)


@dataclass
class FrameBlock:
    """A block of frames in send order: ``ids`` (n,), ``data`` (n, 8) uint8, ``timestamps`` (n,) [s],
    ``dlc`` (n,) or None (all 8: our frames)."""

    ids: NDArray[np.int64]
    data: NDArray[np.uint8]
    timestamps: NDArray[np.float64]
    dlc: NDArray[np.int64] | None = None

    def __len__(self) -> int:
        return int(self.ids.size)

    def take(self, index: NDArray[np.int64] | NDArray[np.bool_]) -> "FrameBlock":
        return FrameBlock(self.ids[index], self.data[index], self.timestamps[index],
                          None if self.dlc is None else self.dlc[index])

    @staticmethod
    def concat(blocks: list["FrameBlock"]) -> "FrameBlock":
        if not blocks:
            return FrameBlock(np.zeros(0, np.int64), np.zeros((0, 8), np.uint8), np.zeros(0))
        dlc = None if all(b.dlc is None for b in blocks) else np.concatenate(
            [np.full(len(b), 8, np.int64) if b.dlc is None else b.dlc for b in blocks])
        return FrameBlock(np.concatenate([b.ids for b in blocks]), np.concatenate([b.data for b in blocks]),
                          np.concatenate([b.timestamps for b in blocks]), dlc)


CrcFn = Callable[[NDArray[np.int64], NDArray[np.uint8]], NDArray[np.uint8]]


class FaultInjector:
    """Stateful fault injector over consecutive blocks (state: silences, stuck signals, delayed frames).

    ``crc_fn(ids, data)`` recomputes the byte-0 CRC of frames (used to keep stuck frames valid).
    """

    def __init__(self, spec: FaultSpec, rng: np.random.Generator, crc_fn: CrcFn) -> None:
        self.spec = spec
        self.rng = rng
        self.crc_fn = crc_fn
        self.counts: dict[str, int] = {k: 0 for k in COUNTER_KEYS}
        self._silence_until = -np.inf
        self._stuck: dict[int, tuple[float, NDArray[np.uint8]]] = {}   # id -> (until, bytes 2..7)
        self._carry = FrameBlock.concat([])

    def apply(self, block: FrameBlock) -> FrameBlock:
        """Faulted version of ``block``; frames delayed past its end are held for the next call."""
        s = self.spec
        if s.silence > 0:
            block = self._silence(block)
        if s.drop > 0:
            keep = self.rng.random(len(block)) >= s.drop
            self.counts["dropped"] += int((~keep).sum())
            block = block.take(keep)
        if s.stuck > 0 or self._stuck:
            block = self._stick(block)
        if s.corrupt > 0:
            block = self._corrupt(block)
        if s.duplicate > 0:
            block = self._duplicate(block)
        if s.reorder > 0:
            block = self._reorder(block)
        if s.delay > 0 or len(self._carry):
            block = self._delay(block)
        return block

    @property
    def holding(self) -> int:
        """Number of delayed frames held back for a later block."""
        return len(self._carry)

    def flush(self) -> FrameBlock:
        """Frames still held back by a delay (call once at the end of the stream)."""
        carry, self._carry = self._carry, FrameBlock.concat([])
        return carry

    # -- individual faults --------------------------------------------------------------------

    def _silence(self, block: FrameBlock) -> FrameBlock:
        starts = np.flatnonzero(self.rng.random(len(block)) < self.spec.silence)
        keep = block.timestamps >= self._silence_until
        for i in starts:
            t0 = block.timestamps[i]
            if t0 < self._silence_until:
                continue   # already silent
            self._silence_until = t0 + self.spec.silence_time
            keep &= ~((block.timestamps >= t0) & (block.timestamps < self._silence_until))
            self.counts["silences"] += 1
        self.counts["silenced"] += int((~keep).sum())
        return block.take(keep)

    def _stick(self, block: FrameBlock) -> FrameBlock:
        motor = (block.ids >= MOTOR_STATE_BASE_ID) & (block.ids < MOTOR_STATE_BASE_ID + 8)
        draws = (self.rng.random(len(block)) < self.spec.stuck) & motor
        touched = set(self._stuck) | set(block.ids[draws].tolist())
        if not touched:
            return block
        data = block.data.copy()
        altered = np.zeros(len(block), dtype=bool)
        for fid in sorted(touched):     # one pass per stuck period, vectorised within it
            rows = np.flatnonzero(block.ids == fid)
            ts, start_rows = block.timestamps[rows], rows[draws[rows]]
            pos = 0                     # rows[pos:] not yet decided
            while pos < rows.size:
                held = self._stuck.get(fid)
                if held is not None:
                    end = pos + int(np.searchsorted(ts[pos:], held[0], side="left"))
                    data[rows[pos:end], 2:] = held[1]
                    altered[rows[pos:end]] = True
                    if end == rows.size:
                        break           # still stuck at the end of the block
                    del self._stuck[fid]
                    pos = end
                nxt = start_rows[start_rows >= rows[pos]]
                if nxt.size == 0:
                    break
                i = int(nxt[0])
                self._stuck[fid] = (block.timestamps[i] + self.spec.stuck_time, data[i, 2:].copy())
                self.counts["stuck_periods"] += 1
                pos = int(np.searchsorted(rows, i)) + 1
        if altered.any():
            data[altered, 0] = self.crc_fn(block.ids[altered], data[altered])
        self.counts["stuck"] += int(altered.sum())
        return FrameBlock(block.ids, data, block.timestamps)

    def _corrupt(self, block: FrameBlock) -> FrameBlock:
        rows = np.flatnonzero(self.rng.random(len(block)) < self.spec.corrupt)
        if rows.size == 0:
            return block
        data = block.data.copy()
        bits = data.reshape(-1, 8)
        for r in rows:
            n_bits = int(self.rng.integers(1, 4))
            for b in self.rng.choice(64, size=n_bits, replace=False):
                bits[r, b // 8] ^= np.uint8(1 << (b % 8))
        self.counts["corrupted"] += int(rows.size)
        return FrameBlock(block.ids, data, block.timestamps)

    def _duplicate(self, block: FrameBlock) -> FrameBlock:
        dup = self.rng.random(len(block)) < self.spec.duplicate
        if not dup.any():
            return block
        index = np.repeat(np.arange(len(block)), 1 + dup.astype(np.int64))
        out = block.take(index)
        second = np.concatenate([[False], index[1:] == index[:-1]])
        out.timestamps = out.timestamps.copy()
        out.timestamps[second] += DUPLICATE_OFFSET_S
        self.counts["duplicated"] += int(dup.sum())
        return out

    def _reorder(self, block: FrameBlock) -> FrameBlock:
        n = len(block)
        if n < 2:
            return block
        chosen = np.flatnonzero(self.rng.random(n - 1) < self.spec.reorder)
        if chosen.size == 0:
            return block
        # non-overlapping swaps (i, i + 1): skip a pick adjacent to the previous accepted one
        swaps: list[int] = []
        for i in chosen:
            if not swaps or i > swaps[-1] + 1:
                swaps.append(int(i))
        order = np.arange(n)
        s = np.asarray(swaps)
        order[s], order[s + 1] = s + 1, s
        self.counts["reordered"] += len(swaps)
        # timestamps stay in place: the frames arrive in swapped order
        return FrameBlock(block.ids[order], block.data[order], block.timestamps)

    def _delay(self, block: FrameBlock) -> FrameBlock:
        delayed = self.rng.random(len(block)) < self.spec.delay
        ts = block.timestamps.copy()
        ts[delayed] += self.rng.uniform(0.0, self.spec.delay_max, size=int(delayed.sum()))
        self.counts["delayed"] += int(delayed.sum())
        merged = FrameBlock.concat([self._carry, FrameBlock(block.ids, block.data, ts)])
        order = np.argsort(merged.timestamps, kind="stable")
        merged = merged.take(order)
        end = block.timestamps[-1] if len(block) else -np.inf
        ready = merged.timestamps <= end
        self._carry = merged.take(~ready)
        return merged.take(ready)
