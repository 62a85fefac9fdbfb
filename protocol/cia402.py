"""CANopen CiA 402 drives: where each object travels in the TPDOs, through the canopen library.

:func:`drive_layout` builds a ``canopen.RemoteNode`` from the drive's EDS/DCF on a ``canopen.Network``
that is never connected, and takes the TPDO communication and mapping parameters from the object
dictionary (``node.tpdo.read(from_od=True)``: no SDO, nothing sent). Each mapped object becomes a
:class:`~protocol.bitfields.BitField` at the offset canopen computed, so blocks of frames decode
vectorised (tests/test_cia402.py checks them against canopen's own ``PdoMap.on_message``). Without an
EDS, the TPDO mapping written in the mapping file is packed as CiA 301 packs it (objects in order, LSB
first) with the standard CiA 402 object sizes below.

Objects (CiA 402): 6041h statusword, 6064h position actual value [inc], 606Ch velocity actual value
[velocity units: here inc/s], 6076h motor rated torque [mN·m], 6077h torque actual value [‰ of 6076h],
608Fh position encoder resolution [inc per motor revolution].
"""

from __future__ import annotations

import io
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from protocol.bitfields import BitField
from protocol.files import read_regular_or
from protocol.signal_mapping import UnreadableFile

STATUSWORD, POSITION, VELOCITY, RATED_TORQUE, TORQUE, ENCODER = 0x6041, 0x6064, 0x606C, 0x6076, 0x6077, 0x608F
#: Statusword bits 0–3, 5, 6 read "operation enabled" (CiA 402 state machine).
OPERATION_ENABLED_MASK, OPERATION_ENABLED = 0x006F, 0x0027
SYNC_ID = 0x080
#: The largest EDS/DCF read (a drive's is ≈ 10–500 kB; canopen parses it whole).
MAX_EDS_BYTES = 4 << 20
#: Standard objects for a TPDO mapping written in the mapping file: (bits, signed).
STANDARD_OBJECTS: dict[int, tuple[int, bool]] = {STATUSWORD: (16, False), POSITION: (32, True),
                                                 VELOCITY: (32, True), TORQUE: (16, True)}
_SIGNED_TYPES = {0x2, 0x3, 0x4, 0x15}      # INTEGER8/16/32/64


class Cia402Error(ValueError):
    """A drive description that cannot be used (the message names the node and the fix)."""


@dataclass(frozen=True)
class PdoField:
    """One object in one TPDO: COB-ID, the TPDO's length [bytes], its transmission type, and the field."""

    cob_id: int
    length: int
    transmission: int
    index: int
    subindex: int
    bits: BitField


@dataclass(frozen=True)
class DriveLayout:
    node: int
    fields: dict[tuple[int, int], PdoField] = field(default_factory=dict)
    rated_torque_nm: float | None = None
    increments_per_revolution: float | None = None

    def find(self, index: int, subindex: int = 0) -> PdoField | None:
        return self.fields.get((index, subindex))

    def tpdos(self) -> dict[int, list[PdoField]]:
        """Fields by COB-ID, in mapping order."""
        out: dict[int, list[PdoField]] = {}
        for f in self.fields.values():
            out.setdefault(f.cob_id, []).append(f)
        return {k: sorted(v, key=lambda f: f.bits.start) for k, v in out.items()}


def open_node(node_id: int, eds: Path, local: bool = False) -> Any:
    """A canopen node from ``eds`` on an unconnected network, its TPDOs read from the object dictionary."""
    import canopen
    text = read_eds(node_id, eds)
    network = canopen.Network()                      # never connected: nothing is ever sent from here
    try:
        node = (canopen.LocalNode if local else canopen.RemoteNode)(node_id, canopen.import_od(text, node_id))
        network.add_node(node)
        node.tpdo.read(from_od=True)
    except Exception as exc:  # noqa: BLE001 — canopen's EDS parser raises configparser/KeyError/ValueError
        first = (str(exc).strip().splitlines() or [""])[0][:300]
        raise Cia402Error(f"node {node_id}: cannot read EDS {eds}: {type(exc).__name__}: {first}") from None
    return node


def read_eds(node_id: int, eds: Path) -> io.StringIO:
    """The EDS/DCF as text for canopen (named like the file, which tells canopen its format): a regular
    file of at most :data:`MAX_EDS_BYTES`, UTF-8 or else Latin-1 (CiA 306 files are ASCII; vendors'
    comments are often Latin-1). Cia402Error if it is not such a file, UnreadableFile on an I/O error."""
    raw = read_regular_or(eds, MAX_EDS_BYTES, f"node {node_id}: EDS file", Cia402Error, UnreadableFile)
    try:
        text = io.StringIO(raw.decode("utf-8"))
    except UnicodeDecodeError:
        text = io.StringIO(raw.decode("latin-1"))
    text.name = str(eds)
    return text


def drive_layout(node_id: int, eds: Path | None = None,
                 tpdo: tuple[tuple[int, tuple[str, ...]], ...] = ()) -> DriveLayout:
    """Where the drive's objects travel (see the module docstring)."""
    if eds is None:
        return _layout_from_config(node_id, tpdo)
    node = open_node(node_id, eds)
    fields: dict[tuple[int, int], PdoField] = {}
    for pdo in node.tpdo.map.values():
        if not pdo.enabled or not pdo.map or pdo.cob_id is None:
            continue
        length = sum(v.length for v in pdo.map) // 8
        for v in pdo.map:
            signed = getattr(v.od, "data_type", None) in _SIGNED_TYPES
            bits = BitField(v.name, int(v.offset), int(v.length), signed=signed)
            fields[(v.index, v.subindex)] = PdoField(int(pdo.cob_id), length, int(pdo.trans_type or 0),
                                                     v.index, v.subindex, bits)
    od = node.object_dictionary
    rated = _default(od, RATED_TORQUE, None)
    increments = _default(od, ENCODER, 1)
    revolutions = _default(od, ENCODER, 2)
    return DriveLayout(node_id, fields, None if rated is None else rated / 1000.0,
                       None if not increments or not revolutions else increments / revolutions)


def _default(od: Any, index: int, subindex: int | None) -> float | None:
    try:
        entry = od[index] if subindex is None else od[index][subindex]
    except KeyError:
        return None
    value = entry.value if getattr(entry, "value", None) is not None else getattr(entry, "default", None)
    try:
        return None if value is None else float(value)
    except (TypeError, ValueError):
        return None


def _layout_from_config(node_id: int, tpdo: tuple[tuple[int, tuple[str, ...]], ...]) -> DriveLayout:
    fields: dict[tuple[int, int], PdoField] = {}
    for cob_id, objects in tpdo:
        offset, parsed = 0, []
        for text in objects:
            try:
                index = int(text, 16)
            except ValueError:
                raise Cia402Error(f"node {node_id}: TPDO 0x{cob_id:X}: object {text!r} is not a hex index "
                                  "such as \"6077\"") from None
            if index not in STANDARD_OBJECTS:
                raise Cia402Error(f"node {node_id}: object {text} has no standard size; give the drive's EDS "
                                  f"(known without it: {[f'{i:04X}' for i in STANDARD_OBJECTS]})")
            bits, signed = STANDARD_OBJECTS[index]
            parsed.append((index, BitField(f"{index:04X}", offset, bits, signed=signed)))
            offset += bits
        if offset > 64:
            raise Cia402Error(f"node {node_id}: TPDO 0x{cob_id:X} maps {offset} bits, more than 8 bytes")
        for index, bits_field in parsed:
            fields[(index, 0)] = PdoField(cob_id, offset // 8, 1, index, 0, bits_field)
    return DriveLayout(node_id, fields)
