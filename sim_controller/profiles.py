"""Other controllers' frames from the same simulated robot: ``--profile native | cia402 | dbc:MAPPING.toml``.

``native`` is our protocol (:meth:`Controller._encode`). The others encode the same physics as another
controller would send it, so the agent's foreign sources are tested with real libraries on both sides:

* ``cia402`` — one CiA 402 drive per joint (node j + 1) described by ``protocol/eds/cia402_drive.eds``:
  every tick a SYNC (0x080) from the controller, then each drive's TPDO1 (statusword, torque actual value
  in ‰ of the rated torque, velocity actual value in inc/s); every 10th SYNC its TPDO2 (position actual
  value, motor temperature in 0.1 °C). The TPDO layouts come from canopen's own ``LocalNode`` objects.
  The statusword reads "operation enabled" except while the robot stands still for a maintenance.
  No load estimate, no cycle marks. Reference (max.) torques :data:`CIA402_REFERENCE_TORQUE_NM`, rated
  torque one third of it.
* ``dbc:MAPPING.toml`` — the frames a mapping file describes, encoded with its DBC's signal definitions:
  per tick one frame per joint with speed and torque; every 10th tick the joint's load and temperature
  frames and the cycle marks, where the mapping has them. ``protocol/mappings/foreign_robot.toml`` is
  the shipped example (big-endian, rpm, N·m, the load multiplexed by axis, no cycle/segment/E2E).

Frames of one tick are spaced like ours; link faults apply to the native profile only.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from importlib import resources
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from protocol import frames as pf
from protocol.bitfields import BitField, resolve
from protocol.cia402 import POSITION, STATUSWORD, SYNC_ID, TORQUE, VELOCITY, drive_layout
from protocol.dbc_files import load_dbc
from protocol.dbc_units import checked_ref
from protocol.signal_mapping import JointMapping, SignalMapping, SignalRef, load_mapping
from sim_controller.faults import FrameBlock

STATUS_EVERY = 10
#: Motor reference (maximum) torques of the simulated CiA 402 joints [N·m]; rated torque = one third.
CIA402_REFERENCE_TORQUE_NM = (30.0, 30.0, 21.0, 9.0, 9.0, 6.0, 6.0, 6.0)
TEMPERATURE_OBJECT = 0x2010
STATUS_ENABLED, STATUS_SWITCHED_ON = 0x0637, 0x0233
#: The mappings shipped with the protocol package (``dbc:NAME`` finds them by name).
SHIPPED_MAPPINGS = Path(str(resources.files("protocol") / "mappings"))


class ProfileError(ValueError):
    """A --profile the simulator cannot speak (the message says why)."""


def eds_path() -> Path:
    return Path(str(resources.files("protocol") / "eds" / "cia402_drive.eds"))


@dataclass
class _Slot:
    """One kind of frame in the tick layout: identifier, DLC and the fields written into it."""

    frame_id: int
    dlc: int
    fields: list[tuple[BitField, Any]]        # (field, value source: callable(sc, rows) -> values)


class _Layout:
    """Frames per tick (``fast``, every tick) and per status tick (``slow``), in send order."""

    def __init__(self, fast: list[_Slot], slow: list[_Slot]) -> None:
        self.fast, self.slow = fast, slow

    def encode(self, sc: Any, spacing: float, start_time: float, rate: float) -> tuple[FrameBlock, NDArray[np.int64]]:
        n = sc.ticks.size
        status = sc.ticks % STATUS_EVERY == 0
        nf, ns = len(self.fast), len(self.slow)
        per_tick = nf + status.astype(np.int64) * ns
        before = np.concatenate([[0], np.cumsum(per_tick)[:-1]])
        total = int(per_tick.sum())
        ids, dlc = np.empty(total, np.int64), np.empty(total, np.int64)
        data, ts = np.zeros((total, 8), np.uint8), np.empty(total)
        t_tick = start_time + (sc.abs_tick + np.arange(n)) / rate
        st = np.flatnonzero(status)
        for k, slot in enumerate(self.fast):
            self._fill(slot, before + k, np.arange(n), sc, ids, dlc, data)
            ts[before + k] = t_tick + k * spacing
        for k, slot in enumerate(self.slow):
            pos = before[st] + nf + k
            self._fill(slot, pos, st, sc, ids, dlc, data)
            ts[pos] = t_tick[st] + (nf + k) * spacing
        return FrameBlock(ids, data, ts, dlc), per_tick

    @staticmethod
    def _fill(slot: _Slot, pos: NDArray[np.int64], rows: NDArray[np.int64], sc: Any, ids: NDArray[np.int64],
              dlc: NDArray[np.int64], data: NDArray[np.uint8]) -> None:
        ids[pos], dlc[pos] = slot.frame_id, slot.dlc
        block = np.zeros((pos.size, 8), np.uint8)
        for bits, source in slot.fields:
            bits.encode_into(block, source(sc, rows))
        data[pos] = block


def _joint(quantity: str, j: int, scale: float = 1.0, offset: float = 0.0) -> Any:
    """Value source: a joint's simulated signal per tick (ticks ``rows``), then · scale + offset."""
    return lambda sc, rows: sc.sim[quantity][j, rows] * scale + offset


def _temperature(j: int, scale: float, offset: float = 0.0) -> Any:
    def source(sc: Any, rows: NDArray[np.int64]) -> NDArray[np.float64]:
        noise = sc.status_noise[j, :rows.size] if rows.size <= sc.status_noise.shape[1] else 0.0
        return (sc.cond.motor_temperature[j] + noise) * scale + offset
    return source


def _const(value: float) -> Any:
    return lambda sc, rows: np.full(rows.size, value)


def cia402_layout(joints: int, eds: Path | None = None) -> _Layout:
    """The drives' TPDOs (canopen's layout of the EDS) as the simulator sends them."""
    fast: list[_Slot] = [_Slot(SYNC_ID, 0, [])]
    slow: list[_Slot] = []
    for j in range(joints):
        layout = drive_layout(j + 1, eds or eds_path())
        t_ref = CIA402_REFERENCE_TORQUE_NM[j]
        rated = t_ref / 3.0
        sources = {STATUSWORD: lambda sc, rows: np.where(sc.mode[rows] == int(pf.Mode.STOPPED),
                                                         STATUS_SWITCHED_ON, STATUS_ENABLED),
                   TORQUE: _joint("torque", j, 1000.0 * t_ref / rated),
                   VELOCITY: _joint("speed", j, (layout.increments_per_revolution or 65536) / (2 * math.pi)),
                   POSITION: _joint("position", j, (layout.increments_per_revolution or 65536) / (2 * math.pi)),
                   TEMPERATURE_OBJECT: _temperature(j, 10.0)}
        for cob_id, fields in sorted(layout.tpdos().items()):
            slot = _Slot(cob_id, fields[0].length, [(f.bits, sources[f.index]) for f in fields if f.index in sources])
            (fast if fields[0].transmission == 1 else slow).append(slot)
    return _Layout(fast, slow)


def dbc_layout(mapping: SignalMapping, joints: int) -> _Layout:
    """The frames of a DBC mapping (see the module docstring)."""
    if mapping.kind != "dbc" or mapping.dbc is None:
        raise ProfileError(f"--profile dbc: {mapping.path} is a {mapping.kind} mapping, not a dbc one")
    db = load_dbc(mapping)                     # MappingError as the agent's: missing, a directory, not a DBC
    fast: list[_Slot] = []
    slow: dict[tuple[int, int], _Slot] = {}

    def put(where: dict[tuple[int, int], _Slot] | list[_Slot], ref: SignalRef, source: Any,
            joint: tuple[JointMapping, str] | None = None) -> None:
        found = resolve(db, ref.message, ref.signal)
        if joint is not None:      # the DBC's unit, as the agent reads it (protocol.dbc_units)
            ref = checked_ref(found, ref, joint[0], joint[1], mapping.where(f"joint.{joint[0].joint}.{joint[1]}"))
        key = (found.frame_id, found.mux_value)
        if isinstance(where, list):
            slot = next((s for s in where if s.frame_id == found.frame_id), None)
            if slot is None:
                slot = _Slot(found.frame_id, 8, [])
                where.append(slot)
        else:
            slot = where.setdefault(key, _Slot(found.frame_id, 8, []))
            if found.mux is not None and not any(b is found.mux for b, _ in slot.fields):
                slot.fields.append((found.mux, _const(found.mux_value)))
        # agent value = decoded · factor + offset  →  decoded = (value − offset) / factor
        slot.fields.append((found.bits, lambda sc, rows: (source(sc, rows) - ref.offset) / ref.factor))

    for j in range(joints):
        jm = mapping.joints.get(j)
        if jm is None or jm.speed is None or jm.torque is None:
            raise ProfileError(f"--profile dbc: the mapping has no speed and torque for joint {j} "
                               f"(it maps joints {sorted(mapping.joints)}); use --joints {len(mapping.joints)}")
        put(fast, jm.speed, _joint("speed", j), (jm, "speed"))
        put(fast, jm.torque, _joint("torque", j), (jm, "torque"))
        if jm.load is not None:
            put(slow, jm.load, _joint("load_estimate", j), (jm, "load"))
        if jm.temperature is not None:
            put(slow, jm.temperature, _temperature(j, 1.0), (jm, "temperature"))
    marks = {"cycle": lambda sc, rows: np.full(rows.size, float(sc.cycle % 65536)),
             "segment": lambda sc, rows: sc.ref.segment[rows].astype(float)}
    for name, source in marks.items():
        ref = getattr(mapping.cycles, name)
        if ref is not None:
            put(slow, ref, source)
    return _Layout(fast, list(slow.values()))


class ProfileEncoder:
    """``encode(simulated cycle, frame spacing) -> (FrameBlock, frames per tick)`` for a profile."""

    def __init__(self, layout: _Layout, start_time: float, rate: float) -> None:
        self.layout, self.start_time, self.rate = layout, start_time, rate

    def encode(self, sc: Any, spacing: float) -> tuple[FrameBlock, NDArray[np.int64]]:
        return self.layout.encode(sc, spacing, self.start_time, self.rate)


def mapping_path(name: str) -> Path:
    """The mapping file ``name`` names: a file there, else a shipped mapping of that name (``foreign_robot``
    or ``foreign_robot.toml`` in ``protocol/mappings``), else ``name`` (loading it then says it is missing)."""
    given = Path(name)
    if given.exists():
        return given
    shipped = SHIPPED_MAPPINGS / (name if name.endswith(".toml") else f"{name}.toml")
    return shipped if given.parent == Path(".") and shipped.is_file() else given


def profile_encoder(profile: str, joints: int, start_time: float, rate: float) -> ProfileEncoder | None:
    """The encoder of ``--profile`` (None: native). Raises ProfileError (or MappingError) with the fix."""
    if profile == "native":
        return None
    if profile == "cia402":
        return ProfileEncoder(cia402_layout(joints), start_time, rate)
    if profile.startswith("dbc:"):
        return ProfileEncoder(dbc_layout(load_mapping(mapping_path(profile[4:])), joints), start_time, rate)
    raise ProfileError(f"profile: native, cia402 or dbc:MAPPING.toml, got {profile!r}")
