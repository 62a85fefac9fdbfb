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
import re
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from protocol.bitfields import BitField
from protocol.console import library_message
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
#: CiA 301 integer data types and their bits (INTEGER8 … 64, UNSIGNED8 … 64): the only ones decoded.
INTEGER_BITS = {0x2: 8, 0x3: 16, 0x4: 32, 0x10: 24, 0x12: 40, 0x13: 48, 0x14: 56, 0x15: 64,
                0x5: 8, 0x6: 16, 0x7: 32, 0x16: 24, 0x18: 40, 0x19: 48, 0x1A: 56, 0x1B: 64}
_SIGNED_TYPES = {0x2, 0x3, 0x4, 0x10, 0x12, 0x13, 0x14, 0x15}
_OTHER_TYPES = {0x1: "BOOLEAN", 0x8: "REAL32", 0x9: "VISIBLE_STRING", 0xA: "OCTET_STRING", 0xB: "UNICODE_STRING",
                0xC: "TIME_OF_DAY", 0xD: "TIME_DIFFERENCE", 0xF: "DOMAIN", 0x11: "REAL64"}
PDO_NOT_VALID = 1 << 31


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
    problem: str | None = None      # why its values cannot be decoded (a data type or mapped length), None: fine


@dataclass(frozen=True)
class DriveLayout:
    node: int
    fields: dict[tuple[int, int], PdoField] = field(default_factory=dict)
    rated_torque_nm: float | None = None
    increments_per_revolution: float | None = None
    encoder: tuple[float | None, float | None] = (None, None)    # 608Fh sub 1, 2 as the EDS gives them
    unused: tuple[str, ...] = ()    # TPDOs that carry nothing (not valid, no objects), for messages

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
        od = canopen.import_od(text, node_id)
        node = (canopen.LocalNode if local else canopen.RemoteNode)(node_id, od)
        network.add_node(node)
        for number, pdo in (node.tpdo.map or {}).items():
            _read_tpdo(f"node {node_id}: EDS file {eds}", node_id, number, pdo)
    except Cia402Error:
        raise
    except Exception as exc:  # noqa: BLE001 — canopen's EDS parser raises configparser/KeyError/ValueError
        raise Cia402Error(f"node {node_id}: cannot read EDS {eds}: {type(exc).__name__}: "
                          f"{library_message(exc)}") from None
    return node


#: An EDS key, canopen's attribute of its text and of its value.
_VALUE_KEYS = (("DefaultValue", "default_raw", "default"), ("ParameterValue", "value_raw", "value"))


def _section(var: Any) -> str:
    """The EDS section of an object dictionary entry: ``6076`` or ``1A00sub1``."""
    return f"{var.index:04X}" if getattr(var, "parent", None) is None or not hasattr(var.parent, "subindices") \
        else f"{var.index:04X}sub{var.subindex:X}"


def _number(where: str, var: Any, needed: bool = False) -> Any:
    """The value canopen read for the integer entry ``var`` (its ParameterValue, else its DefaultValue, else
    None), called where the value is used. Cia402Error naming the section if a value is given but is no number
    (canopen leaves it unset: a TPDO could not be placed, a scale would be missing), or, ``needed``, if none is
    given. An empty value counts as not given, as canopen reads it. ``where`` begins the message."""
    if getattr(var, "data_type", None) in INTEGER_BITS:
        for key, raw, value in _VALUE_KEYS:
            text = getattr(var, raw, None)
            if text is not None and str(text).strip() and getattr(var, value, None) is None:
                raise Cia402Error(f"{where}: [{_section(var)}] {key}={text!r} is not a number: write an integer "
                                  "(e.g. 0x60410010, 3 or $NODEID+0x180)")
    found = _raw(var)
    if needed and found is None:
        raise Cia402Error(f"{where}: [{_section(var)}] has no value (DefaultValue empty): write the object it maps "
                          "(e.g. 0x60410010) or lower the count in sub0")
    return found


def _raw(entry: Any) -> Any:
    return entry.value if getattr(entry, "value", None) is not None else getattr(entry, "default", None)


def _read_tpdo(eds_where: str, node_id: int, number: int, pdo: Any) -> None:
    """``pdo.read(from_od=True)`` where the EDS describes a TPDO canopen can place, else Cia402Error naming the
    entry: canopen only logs a mapped object the EDS lacks and places the objects after it too early
    (values read from the wrong bits), and only logs a mapping of more than 64 bits. A TPDO not valid
    (COB-ID bit 31) is not read: it is never sent. ``eds_where`` begins a message on a value of the EDS."""
    where = f"node {node_id}: TPDO{number} (mapping {0x1A00 + number - 1:04X}h)"
    communication = pdo.com_record.od
    if isinstance(cob := _number(eds_where, communication[1]), int) and cob & PDO_NOT_VALID:
        return
    if 2 in communication.subindices:
        _number(eds_where, communication[2])              # the transmission type, read by pdo.read below
    array = pdo.map_array.od
    count = _number(eds_where, array[0])
    bits = 0
    for sub in range(1, (count if isinstance(count, int) else 0) + 1):
        try:
            array[sub]
        except KeyError:
            raise Cia402Error(f"{where}: sub-index 0 says {count} mapped objects, entry {sub} is not in the EDS: "
                              f"fix {0x1A00 + number - 1:04X}sub0 or add the entries") from None
        value = int(_number(eds_where, array[sub], needed=True))
        index, subindex, size = value >> 16, (value >> 8) & 0xFF, value & 0xFF
        if not (index and size):
            continue
        bits += size
        if not _describes(pdo.pdo_node.node.object_dictionary, index, subindex):
            dummy = (f" (a dummy entry: declare it in [DummyUsage] as Dummy{index:04d}=1)"
                     if 1 <= index <= 7 else "")
            raise Cia402Error(f"{where}: entry {sub} (0x{value:08X}) maps object {index:04X}sub{subindex}, which "
                              f"the EDS does not describe{dummy}: the objects after it cannot be placed; "
                              "give the drive's complete EDS/DCF") from None
    if bits > 64:
        raise Cia402Error(f"{where}: maps {bits} bits, more than a CAN frame's 64: fix its entries (each entry's "
                          "last byte is the object's length in bits)")
    pdo.read(from_od=True)


def _describes(od: Any, index: int, subindex: int) -> bool:
    """Whether the object dictionary ``od`` has object ``index`` (sub ``subindex`` of a record or array)."""
    from canopen import objectdictionary

    try:
        obj = od[index]
        if isinstance(obj, (objectdictionary.ODRecord, objectdictionary.ODArray)):
            obj[subindex]
    except KeyError:
        return False
    return True


def _problem(od: Any, size: int) -> str | None:
    """Why an object mapped with ``size`` bits cannot be decoded as an integer, or None."""
    data_type = getattr(od, "data_type", None)
    if data_type not in INTEGER_BITS:
        name = (_OTHER_TYPES.get(data_type, f"0x{data_type:04X}") if isinstance(data_type, int)
                else repr(data_type))
        return f"has data type {name}: only integers (INTEGER8 … 64, UNSIGNED8 … 64) are decoded"
    if size != INTEGER_BITS[data_type]:
        return f"is mapped with {size} bits, its data type has {INTEGER_BITS[data_type]}"
    return None


def read_eds(node_id: int, eds: Path) -> io.StringIO:
    """The EDS/DCF as text for canopen (named like the file, which tells canopen its format): a regular
    file of at most :data:`MAX_EDS_BYTES`, UTF-8 or else Latin-1 (CiA 306 files are ASCII; vendors'
    comments are often Latin-1). Cia402Error if it is not such a file, is empty or has no object's section,
    UnreadableFile on an I/O error."""
    raw = read_regular_or(eds, MAX_EDS_BYTES, f"node {node_id}: EDS file", Cia402Error, UnreadableFile)
    try:
        text = io.StringIO(raw.decode("utf-8"))
    except UnicodeDecodeError:
        text = io.StringIO(raw.decode("latin-1"))
    if not any(line.strip() and line.lstrip()[0] not in ";#" for line in text.getvalue().splitlines()):
        what = "empty (0 bytes)" if not raw else "empty (no line but blanks and comments)"
        raise Cia402Error(f"node {node_id}: EDS file {eds} is {what}: give the drive's EDS/DCF")
    if not re.search(r"(?m)^\s*\[[0-9A-Fa-f]{4}(sub[0-9A-Fa-f]+)?\]", text.getvalue()):
        raise Cia402Error(f"node {node_id}: EDS file {eds} describes no object (no section such as [1000] or "
                          "[1A00sub1]): not an EDS/DCF; give the drive's EDS")
    text.name = str(eds)
    return text


def drive_layout(node_id: int, eds: Path | None = None,
                 tpdo: tuple[tuple[int, tuple[str, ...]], ...] = ()) -> DriveLayout:
    """Where the drive's objects travel (see the module docstring)."""
    if eds is None:
        return _layout_from_config(node_id, tpdo)
    node = open_node(node_id, eds)
    fields: dict[tuple[int, int], PdoField] = {}
    unused = []
    for number, pdo in node.tpdo.map.items():
        if not pdo.enabled or not pdo.map or pdo.cob_id is None:
            unused.append(f"TPDO{number} " + ("maps no object" if pdo.enabled else "is not valid (COB-ID bit 31)"))
            continue
        length = sum(v.length for v in pdo.map) // 8
        for v in pdo.map:
            signed = getattr(v.od, "data_type", None) in _SIGNED_TYPES
            bits = BitField(v.name, int(v.offset), int(v.length), signed=signed)
            fields[(v.index, v.subindex)] = PdoField(int(pdo.cob_id), length, int(pdo.trans_type or 0),
                                                     v.index, v.subindex, bits, _problem(v.od, int(v.length)))
    od, where = node.object_dictionary, f"node {node_id}: EDS file {eds}"
    rated = _default(where, od, RATED_TORQUE, None)
    increments = _default(where, od, ENCODER, 1)
    revolutions = _default(where, od, ENCODER, 2)
    per_rev = increments / revolutions if increments and revolutions and increments > 0 < revolutions else None
    return DriveLayout(node_id, fields, None if rated is None else rated / 1000.0, per_rev,
                       (increments, revolutions), tuple(unused))


def _default(where: str, od: Any, index: int, subindex: int | None) -> float | None:
    """The value of object ``index`` (sub ``subindex``) in the EDS, None where it has none."""
    try:
        entry = od[index] if subindex is None else od[index][subindex]
    except KeyError:
        return None
    value = _number(where, entry)
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
