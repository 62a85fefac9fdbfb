"""CANopen CiA 402 drives, listen-only: TPDOs → per-joint samples (docs/CONNECTING.md).

Per joint a drive (node id, EDS/DCF or a TPDO mapping in the mapping file). Where each object travels
comes from canopen's PDO machinery (:func:`protocol.cia402.drive_layout`: ``node.tpdo.read(from_od=True)``
on a network that is never connected, so nothing is sent); frames are then decoded vectorised at the
offsets canopen computed. Torque actual value 6077h is in ‰ of the motor rated torque 6076h (from the
mapping's ``rated_torque_nm`` or the EDS default), scaled to the agent's fraction of T_ref
(``reference_torque_nm``); velocity actual value 606Ch in velocity units times ``velocity_factor``
(default: inc/s of the encoder resolution 608Fh). Samples count only while the drive's statusword 6041h
reads "operation enabled" (the last statusword of that node in stream order; the others are counted as
``not_enabled``). A vendor temperature object (and a load object, if a drive has one) enter per frame.
A TPDO shorter than its PDO mapping (CiA 301: a PDO length error) is dropped and counted as ``malformed``:
its missing bytes are not values.

Resolution: ‰ of rated torque is 1e-3 · rated / T_ref of our fraction (3.3e-4 with T_ref = 3 × rated),
6.7 × our frames' 5e-5; docs/CONNECTING.md says what that costs.
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import NDArray

from edge_monitor.sources.foreign_source import BoundSignal, ForeignCounters, short_frames, status_columns
from edge_monitor.sources.ingest import _forward_index
from edge_monitor.sources.samples import DecodedSamples, JointColumns
from protocol.cia402 import (
    OPERATION_ENABLED,
    OPERATION_ENABLED_MASK,
    STATUSWORD,
    SYNC_ID,
    TORQUE,
    VELOCITY,
    Cia402Error,
    DriveLayout,
    drive_layout,
)
from protocol.mapping_limits import TORQUE_NM, VELOCITY_FACTOR, within
from protocol.signal_mapping import JointMapping, MappingError, SignalMapping
from protocol.units import UnitError, torque_factor


class Cia402Decoder:
    """Frame blocks of CiA 402 drives → :class:`DecodedSamples` (see the module docstring)."""

    def __init__(self, mapping: SignalMapping) -> None:
        self.mapping = mapping
        self.c = ForeignCounters()
        self.joints: dict[int, tuple[BoundSignal, BoundSignal, BoundSignal | None]] = {}
        self.status: dict[int, dict[str, BoundSignal]] = {}
        self._last_status: dict[int, int] = {}
        known = {SYNC_ID}
        for j, jm in mapping.joints.items():
            where = mapping.where(f"joint.{j}")
            try:
                layout = drive_layout(int(jm.node or 0), jm.eds, jm.tpdo)
            except Cia402Error as exc:
                raise MappingError(f"{where}: {exc}") from None
            self.joints[j] = self._bind_joint(jm, layout, where)
            self.status[j] = {q: self._bind_object(layout, ref.index or 0, ref.subindex, ref.factor, ref.offset,
                                                   f"{where}.{q}")
                              for q in ("load", "temperature") if (ref := getattr(jm, q)) is not None}
            known |= {f.cob_id for f in layout.fields.values()} | {0x700 + layout.node, 0x80 + layout.node}
        self.known = np.array(sorted(known), dtype=np.int64)
        self.bounds = [b for j, (s, t, g) in self.joints.items() for b in (s, t, g, *self.status[j].values())
                       if b is not None]

    def _bind_joint(self, jm: JointMapping, layout: DriveLayout,
                    where: str) -> tuple[BoundSignal, BoundSignal, BoundSignal | None]:
        rated = jm.rated_torque_nm or layout.rated_torque_nm
        if rated is not None and not (within(rated, TORQUE_NM) and rated > 0):
            raise MappingError(f"{where}: the EDS's motor rated torque 6076h of node {layout.node} is "
                               f"{rated * 1e3:g} mN·m, no motor's ({TORQUE_NM[0]:g} … {TORQUE_NM[1]:g} N·m): "
                               "state rated_torque_nm in the mapping or fix the EDS")
        try:
            t_factor = torque_factor("permille", where, jm.reference_torque_nm, rated)
        except UnitError as exc:
            raise MappingError(f"{exc} (rated torque: 6076h of the EDS, or rated_torque_nm)") from None
        v_factor = jm.velocity_factor
        if v_factor is None:
            increments, revolutions = layout.encoder
            if increments is None or revolutions is None:
                raise MappingError(f"{where}: velocity_factor: rad/s per unit of 606Ch is needed (the EDS has no "
                                   "608Fh encoder resolution to assume inc/s)")
            v_factor = 2.0 * math.pi / layout.increments_per_revolution if layout.increments_per_revolution else 0.0
            if not within(v_factor, VELOCITY_FACTOR):
                raise MappingError(f"{where}: the EDS's encoder resolution 608Fh of node {layout.node} is "
                                   f"{increments:g} increments per {revolutions:g} revolutions, no encoder's"
                                   + (f" (606Ch in inc/s would be {v_factor:g} rad/s per unit, outside "
                                      f"{VELOCITY_FACTOR[0]:g} … {VELOCITY_FACTOR[1]:g})" if v_factor else "")
                                   + ": state velocity_factor "
                                   "(rad/s per unit of 606Ch) in the mapping or fix the EDS")
        torque = self._bind_object(layout, TORQUE, 0, t_factor, 0.0, f"{where}: torque actual value")
        speed = self._bind_object(layout, VELOCITY, 0, v_factor, 0.0, f"{where}: velocity actual value")
        if torque.frame_id != speed.frame_id:
            raise MappingError(f"{where}: 6077h and 606Ch must travel in one TPDO (each frame is one sample); "
                               f"they are in 0x{torque.frame_id:X} and 0x{speed.frame_id:X}")
        status = layout.find(STATUSWORD)
        if status is not None and status.problem is not None:
            raise MappingError(f"{where}: statusword 6041h of node {layout.node} (TPDO 0x{status.cob_id:X}) "
                               f"{status.problem}: fix the EDS (CiA 402: UNSIGNED16)")
        gate = None if status is None else BoundSignal("statusword", status.cob_id, status.bits, length=status.length)
        return speed, torque, gate

    @staticmethod
    def _bind_object(layout: DriveLayout, index: int, subindex: int, factor: float, offset: float,
                     where: str) -> BoundSignal:
        found = layout.find(index, subindex)
        if found is None:
            mapped = sorted(f"{i:04X}sub{s}" for i, s in layout.fields)
            unused = f"; {', '.join(layout.unused)}" if layout.unused else ""
            raise MappingError(f"{where}: object {index:04X}sub{subindex} of node {layout.node} is in no TPDO "
                               f"(mapped: {mapped}{unused})")
        if found.problem is not None:
            raise MappingError(f"{where}: object {index:04X}sub{subindex} of node {layout.node} (TPDO "
                               f"0x{found.cob_id:X}) {found.problem}: fix the EDS"
                               + (" (CiA 402: 6077h INTEGER16, 606Ch INTEGER32)"
                                  if index in (TORQUE, VELOCITY) else ""))
        return BoundSignal(found.bits.name, found.cob_id, found.bits, factor, offset, length=found.length)

    def describe(self) -> dict[int, dict[str, str]]:
        return {j: {"speed": f"0x{s.frame_id:X} {s.name}", "torque": f"0x{t.frame_id:X} {t.name}",
                    "gate": "statusword operation enabled" if g is not None else "none (no 6041h in a TPDO)",
                    **{q: f"0x{b.frame_id:X} {b.name}" for q, b in self.status[j].items()}}
                for j, (s, t, g) in self.joints.items()}

    def decode(self, ids: NDArray, data: NDArray, dlc: NDArray, timestamps: NDArray) -> DecodedSamples:
        ids = np.asarray(ids, dtype=np.int64)
        data = np.asarray(data, dtype=np.uint8).reshape(-1, 8)
        times = np.asarray(timestamps, dtype=np.float64)
        self.c.frames_total += int(ids.size)
        dlc = np.asarray(dlc, dtype=np.int64)
        known = np.isin(ids, self.known)
        self.c.unknown_id += int((~known).sum())
        short = known & short_frames(self.bounds, ids, dlc)
        self.c.malformed += int(short.sum())
        known &= ~short
        self.c.frames_ok += int(known.sum())
        out = DecodedSamples()
        for j, (speed, torque, gate) in self.joints.items():
            rows = speed.rows(ids, data, known)
            enabled = self._enabled(j, gate, ids, data, rows, known)
            self.c.not_enabled += int((~enabled).sum())
            rows = rows[enabled]
            out.joints[j] = JointColumns(times[rows], speed.values(data[rows]), torque.values(data[rows]))
            if self.status[j]:
                out.status[j] = status_columns(self.status[j], ids, data, times, known, np.zeros(ids.size, bool))
        return out

    def _enabled(self, joint: int, gate: BoundSignal | None, ids: NDArray[np.int64], data: NDArray[np.uint8],
                 rows: NDArray[np.int64], usable: NDArray[np.bool_]) -> NDArray[np.bool_]:
        """Whether the node's statusword in force at each sample row reads "operation enabled"."""
        if gate is None:
            return np.ones(rows.size, dtype=bool)
        status_rows = gate.rows(ids, data, usable)
        words = gate.bits.raw(data[status_rows]).astype(np.int64)
        at, seen = _forward_index(ids.size, status_rows)
        carry = self._last_status.get(joint, -1)
        word = np.where(seen[rows], words[at[rows]] if words.size else carry, carry)
        if words.size:
            self._last_status[joint] = int(words[-1])
        return (word >= 0) & ((word & OPERATION_ENABLED_MASK) == OPERATION_ENABLED)
