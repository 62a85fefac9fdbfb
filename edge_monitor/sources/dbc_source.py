"""Any DBC: a controller's frames decoded with cantools' signal definitions through a mapping file.

Each mapped quantity is resolved once against the DBC (message, signal, multiplexer) and decoded
vectorised with :class:`~protocol.bitfields.BitField` (the same values as ``Message.decode``,
tests/test_bitfields.py). Speed and torque of a joint must come in one message: each such frame is one
sample. Each mapped joint signal's unit in the DBC is checked against the mapping's
(:mod:`protocol.dbc_units`: converted, or refused naming the key to fix). A frame shorter than a mapped
signal in it needs is dropped and counted (``malformed``); a
message with an extended (29-bit) identifier matches extended frames only. Load estimate, motor
temperature and cycle marks may come in any message, at any rate.
E2E (optional, per message): AUTOSAR profile 2 or 5, the CRC checked with ``cantools.autosar.end_to_end``
and the counter (profile 2: low nibble of byte 1; profile 5: byte 2) checked for gaps and repeats;
a frame with a wrong CRC or a repeated counter is dropped and counted.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass
from typing import Any, Callable

import numpy as np
from numpy.typing import NDArray

from edge_monitor.sources.foreign_source import BoundSignal, ForeignCounters, short_frames, status_columns, take
from edge_monitor.sources.samples import DecodedSamples, JointColumns
from protocol.bitfields import BitFieldError, ResolvedSignal, resolve
from protocol.dbc_files import load_dbc
from protocol.dbc_units import checked_ref
from protocol.frame_blocks import CAN_EFF_FLAG
from protocol.signal_mapping import E2EMapping, JointMapping, MappingError, SignalMapping, SignalRef

log = logging.getLogger(__name__)

def bind(db: Any, ref: SignalRef, where: str, found: ResolvedSignal | None = None) -> BoundSignal:
    """``ref`` resolved against the DBC ``db`` (or as already ``found`` there); a missing message or signal names
    the nearest ones."""
    found = found or _resolve(db, ref, where)
    message = db.get_message_by_name(found.message)
    check_place(message, message.get_signal_by_name(found.bits.name), where)
    return BoundSignal(f"{found.message}.{found.bits.name}", frame_key(message),
                       found.bits, ref.factor, ref.offset, found.mux, found.mux_value)


def _resolve(db: Any, ref: SignalRef, where: str) -> ResolvedSignal:
    try:
        return resolve(db, ref.message, ref.signal)
    except BitFieldError as exc:
        raise MappingError(f"{where}: {exc}") from None


def bind_quantity(db: Any, jm: JointMapping, quantity: str, where: str, unitless: list[str]) -> BoundSignal:
    """:func:`bind` for a joint's ``quantity``, its unit checked against the DBC's
    (:func:`protocol.dbc_units.checked_ref`; a signal without unit in the DBC is added to ``unitless``)."""
    ref = getattr(jm, quantity)
    found = _resolve(db, ref, where)
    if not found.unit:
        unitless.append(f"{found.message}.{found.bits.name}")
    return bind(db, checked_ref(found, ref, jm, quantity, where), where, found)


def signal_bits(signal: Any) -> set[int]:
    """Bits of a cantools signal in the frame, numbered byte · 8 + bit (bit 0 the least significant)."""
    if signal.byte_order == "little_endian":
        return set(range(signal.start, signal.start + signal.length))
    bits, pos = set(), signal.start                # Motorola: from the most significant bit, sawtooth order
    for _ in range(signal.length):
        bits.add(pos)
        pos = pos + 15 if pos % 8 == 0 else pos - 1
    return bits


def check_place(message: Any, signal: Any, where: str) -> None:
    """MappingError when a mapped signal does not fit in its message's length or shares bits with another
    signal present in the same frames (cantools reads the DBC with ``strict=False``, so that signals the
    mapping does not use may be sloppy; the mapped ones must not be)."""
    bits = signal_bits(signal)
    if max(bits) >= 8 * int(message.length) or min(bits) < 0:
        raise MappingError(f"{where}: signal {message.name}.{signal.name} (start bit {signal.start}, {signal.length} "
                           f"bits) does not fit in the message's {message.length} bytes: fix the DBC")
    mine = set(signal.multiplexer_ids or ())
    for other in message.signals:
        theirs = set(other.multiplexer_ids or ())
        if other is signal or (mine and theirs and not mine & theirs):     # never in the same frame
            continue
        if bits & signal_bits(other):
            raise MappingError(f"{where}: signals {message.name}.{signal.name} and {other.name} overlap (bits "
                               f"{sorted(bits & signal_bits(other))[:8]}): fix the DBC")


def check_shared_ids(bound: list[tuple[str, BoundSignal]], where: Callable[[str], str]) -> None:
    """MappingError when two mapped signals of different messages would be decoded from the same frames
    (one frame id and multiplexer value: a DBC with two messages on one id; cantools only warns)."""
    for i, (where_a, a) in enumerate(bound):
        for where_b, b in bound[i + 1:]:
            msg_a, msg_b = a.name.split(".")[0], b.name.split(".")[0]
            if a.frame_id == b.frame_id and msg_a != msg_b and (a.mux is None or b.mux is None
                                                                or a.mux_value == b.mux_value):
                raise MappingError(f"{where(where_a)} ({a.name}) and {where_b} ({b.name}): messages {msg_a} and "
                                   f"{msg_b} have one frame id 0x{a.frame_id & ~CAN_EFF_FLAG:X}: both would decode the "
                                   "same frames; fix the DBC")


def frame_key(message: Any) -> int:
    """A DBC message's identifier as frame blocks carry it: an extended (29-bit) one with ``CAN_EFF_FLAG``,
    so it never matches a standard frame of the same number."""
    return int(message.frame_id) | (CAN_EFF_FLAG if message.is_extended_frame else 0)


@dataclass
class _Protection:
    """E2E of one message: its cantools message and the mapping's profile, and the last counter seen."""

    message: Any
    spec: E2EMapping
    last_counter: int | None = None


class DbcDecoder:
    """Frame blocks → :class:`DecodedSamples` (see the module docstring)."""

    def __init__(self, mapping: SignalMapping) -> None:
        db = load_dbc(mapping)
        self.mapping = mapping
        self.c = ForeignCounters()
        self.joints: dict[int, tuple[BoundSignal, BoundSignal]] = {}
        self.status: dict[int, dict[str, BoundSignal]] = {}
        unitless: list[str] = []
        for j, jm in mapping.joints.items():
            where = mapping.where(f"joint.{j}")
            assert jm.speed is not None and jm.torque is not None
            speed = bind_quantity(db, jm, "speed", f"{where}.speed", unitless)
            torque = bind_quantity(db, jm, "torque", f"{where}.torque", unitless)
            if (speed.frame_id, speed.mux_value) != (torque.frame_id, torque.mux_value):
                raise MappingError(f"{where}: speed ({speed.name}) and torque ({torque.name}) must come in one "
                                   "message: each frame is one sample")
            self.joints[j] = (speed, torque)
            self.status[j] = {q: bind_quantity(db, jm, q, f"{where}.{q}", unitless) for q in ("load", "temperature")
                              if getattr(jm, q) is not None}
        if unitless:
            log.info("%s: the DBC gives no unit for %s: read in the units the mapping states (or its defaults)",
                     mapping.where("dbc"), ", ".join(sorted(set(unitless))))
        c = mapping.cycles
        self.marks = {name: bind(db, ref, mapping.where(f"cycles.{name}")) for name in ("cycle", "segment", "trigger")
                      if (ref := getattr(c, name)) is not None}
        self.known = np.array(sorted({frame_key(m) for m in db.messages}), dtype=np.int64)
        self.bounds = [b for j, (s, t) in self.joints.items() for b in (s, t, *self.status[j].values())]
        self.bounds += list(self.marks.values())
        check_shared_ids([(f"joint.{j}", b) for j, (s, t) in self.joints.items()
                          for b in (s, t, *self.status[j].values())]
                         + [(f"cycles.{name}", b) for name, b in self.marks.items()], mapping.where)
        self.protected: dict[int, _Protection] = {}
        for spec in mapping.e2e:
            try:
                message = db.get_message_by_name(spec.message)
            except KeyError:
                raise MappingError(f"{mapping.where('e2e')}: message {spec.message!r} is not in the DBC") from None
            names = [s.name for s in message.signals]
            if spec.counter_signal is not None and spec.counter_signal not in names:
                raise MappingError(f"{mapping.where('e2e')}: counter_signal {spec.counter_signal!r} is not a signal "
                                   f"of {spec.message} (it has {names})")
            self.protected[frame_key(message)] = _Protection(message, spec)

    def describe(self) -> dict[int, dict[str, str]]:
        return {j: {"speed": s.name, "torque": t.name, **{q: b.name for q, b in self.status[j].items()}}
                for j, (s, t) in self.joints.items()}

    def decode(self, ids: NDArray, data: NDArray, dlc: NDArray, timestamps: NDArray) -> DecodedSamples:
        ids = np.asarray(ids, dtype=np.int64)
        data = np.asarray(data, dtype=np.uint8).reshape(-1, 8)
        times = np.asarray(timestamps, dtype=np.float64)
        dlc = np.asarray(dlc, dtype=np.int64)
        self.c.frames_total += int(ids.size)
        known = np.isin(ids, self.known)
        self.c.unknown_id += int((~known).sum())
        short = known & short_frames(self.bounds, ids, dlc)       # cut before a mapped signal: counted, dropped
        self.c.malformed += int(short.sum())
        usable = known & ~short
        usable &= self._e2e(ids, data, usable)
        out = DecodedSamples()
        used = np.zeros(ids.size, dtype=bool)
        for j, (speed, torque) in self.joints.items():
            rows = speed.rows(ids, data, usable)
            used[rows] = True
            out.joints[j] = JointColumns(times[rows], speed.values(data[rows]), torque.values(data[rows]))
        for j, bounds in self.status.items():
            out.status[j] = status_columns(bounds, ids, data, times, usable, used)
        for name, bound in self.marks.items():
            rows, t, values = take(bound, ids, data, times, usable)
            used[rows] = True
            out.marks[name] = (t, values)
        self.c.frames_ok += int(used.sum())
        return out

    def _e2e(self, ids: NDArray[np.int64], data: NDArray[np.uint8], checked: NDArray[np.bool_]) -> NDArray[np.bool_]:
        """Rows that pass their message's E2E check (all rows of unprotected messages; only ``checked`` rows
        are checked and counted)."""
        ok = np.ones(ids.size, dtype=bool)
        if not self.protected:
            return ok
        from cantools.autosar.end_to_end import check_profile2_crc, check_profile5_crc
        for frame_id, prot in self.protected.items():
            spec = prot.spec
            for r in np.flatnonzero((ids == frame_id) & checked).tolist():      # per frame: cantools' own check
                payload = bytes(data[r])
                if spec.profile == 2:
                    counter = payload[1] & 0x0F
                    good = check_profile2_crc(payload, spec.data_ids[counter])
                    modulus = 16
                else:
                    counter = payload[2]
                    good = check_profile5_crc(payload, int(spec.data_id or 0))
                    modulus = 256
                if not good:
                    self.c.crc_errors += 1
                    ok[r] = False
                    continue
                if prot.last_counter is not None:
                    step = (counter - prot.last_counter) % modulus
                    if step == 0:
                        self.c.repeated += 1
                        ok[r] = False
                        continue
                    self.c.counter_lost += step - 1
                prot.last_counter = counter
        return ok
