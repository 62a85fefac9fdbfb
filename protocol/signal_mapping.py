"""The mapping file (TOML): which signals of a foreign controller carry each joint's speed, torque and,
where it has them, motor temperature, load estimate and cycle marks, in which units (docs/CONNECTING.md).

Three kinds share one layout: ``dbc`` (any DBC, decoded with cantools' signal definitions), ``cia402``
(CANopen drives, TPDOs from an EDS through the canopen library) and ``trace`` (CSV/Parquet tables).
:func:`load_mapping` validates the file once and raises :class:`MappingError` naming the key and the fix;
whether the named messages, signals and objects exist is checked against the DBC/EDS by the sources.
"""

from __future__ import annotations

import tomllib
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Mapping

from protocol.catalogue import MAX_JOINTS
from protocol.files import read_regular_or
from protocol.mapping_limits import (
    GEAR_RATIO,
    MAX_LEVEL_SPEED,
    SCALE,
    TORQUE_NM,
    VELOCITY_FACTOR,
    duplicate_joint,
    within,
)
from protocol.numbers import is_finite_number
from protocol.units import UnitError, conversion

KINDS = ("dbc", "cia402", "trace")
#: Text encodings of trace tables (pyarrow transcodes the others to UTF-8).
ENCODINGS = ("utf-8", "cp1252", "latin-1", "iso-8859-1", "utf-16")
CYCLE_SOURCES = ("controller", "motion", "trigger")
QUANTITIES = ("speed", "torque", "temperature", "load")
#: A mapping file is a few kilobytes (64 joints: ≈ 20 kB); larger is not a mapping.
MAX_MAPPING_BYTES = 1 << 20
#: Joint indices a mapping may name (as the agent config: 0 … MAX_JOINTS - 1).
MAX_JOINT = MAX_JOINTS - 1


class MappingError(ValueError):
    """Invalid mapping file; the message names the file, the key and the fix."""


class UnreadableFile(OSError):
    """A mapping, DBC or EDS file that is there but cannot be read (an I/O error): a runtime failure
    (exit code 1), where a file that does not fit is a MappingError (exit code 2)."""


@dataclass(frozen=True)
class SignalRef:
    """Where one quantity comes from and its linear conversion to the agent's unit
    (agent value = decoded value · factor + offset)."""

    message: str | None = None       # DBC message (dbc)
    signal: str | None = None        # DBC signal (dbc)
    column: str | None = None        # table column (trace)
    index: int | None = None         # CANopen object index (cia402 vendor objects)
    subindex: int = 0
    unit: str = ""
    factor: float = 1.0
    offset: float = 0.0
    unit_stated: bool = False        # the mapping names the unit (else a default or a table header's)
    scale: float | None = None       # the mapping's scale (part of factor), None if it states none

    def describe(self) -> str:
        if self.column is not None:
            return f"column {self.column!r}"
        if self.index is not None:
            return f"object 0x{self.index:04X}sub{self.subindex}"
        return f"{self.message}.{self.signal}"


@dataclass(frozen=True)
class JointMapping:
    joint: int
    speed: SignalRef | None = None
    torque: SignalRef | None = None
    temperature: SignalRef | None = None
    load: SignalRef | None = None
    reference_torque_nm: float | None = None
    rated_torque_nm: float | None = None
    gear_ratio: float = 1.0
    side: str = "motor"
    node: int | None = None          # CANopen node id (cia402)
    eds: Path | None = None          # its EDS/DCF (cia402)
    velocity_factor: float | None = None   # rad/s per unit of 0x606C (cia402; default 2π / 0x608F)
    tpdo: tuple[tuple[int, tuple[str, ...]], ...] = ()   # (COB-ID, objects) written in the mapping (cia402)
    key: str | None = None           # value of the joint column in a long table (trace)


@dataclass(frozen=True)
class CycleMapping:
    """How cycles are found: the controller's own marks, the motion, or a trigger signal."""

    source: str = "motion"
    speeds: tuple[float, ...] = ()   # designed test-cycle levels in order [rad/s, motor side]
    reference_joint: int | None = None
    cycle: SignalRef | None = None
    segment: SignalRef | None = None
    trigger: SignalRef | None = None
    trigger_value: float = 1.0


@dataclass(frozen=True)
class E2EMapping:
    """AUTOSAR E2E protection of one DBC message (profile 2 or 5, checked with cantools.autosar)."""

    message: str
    profile: int
    counter_signal: str | None = None
    data_id: int | None = None               # profile 5
    data_ids: tuple[int, ...] = ()           # profile 2: one per counter value (16)


@dataclass(frozen=True)
class TraceFormat:
    layout: str = "wide"             # wide (one column per joint and quantity) | long (a joint column)
    separator: str = ","
    decimal: str = "."
    time_column: str = "time"
    time_unit: str = "s"             # s | ms
    joint_column: str | None = None  # long tables
    encoding: str = "utf-8"          # utf-8 | cp1252 | latin-1 (what Windows trace tools often write)


@dataclass(frozen=True)
class SignalMapping:
    kind: str
    path: Path | None
    joints: dict[int, JointMapping]
    cycles: CycleMapping = field(default_factory=CycleMapping)
    dbc: Path | None = None
    e2e: tuple[E2EMapping, ...] = ()
    listen_only: bool = True
    read_mapping: str = "eds"        # cia402: eds (no SDO) | sdo (opt-in, needs listen_only = false)
    trace: TraceFormat | None = None
    rate_hz: float | None = None

    def where(self, key: str) -> str:
        return f"mapping {self.path.name if self.path else '<text>'}: {key}"


def load_mapping(path: str | Path, commissioning: bool = False) -> SignalMapping:
    """The mapping file at ``path``, validated (``commissioning``: ``[cycles] speeds`` may still be missing,
    for check-mapping to find them)."""
    p = Path(path)
    raw = read_regular_or(p, MAX_MAPPING_BYTES, "mapping file", MappingError, UnreadableFile)
    try:
        data = tomllib.loads(raw.decode("utf-8-sig"))      # a byte-order mark (Windows editors) is no content
    except UnicodeDecodeError as exc:
        raise MappingError(f"mapping file {p} is not UTF-8 text: {exc}") from None
    except (tomllib.TOMLDecodeError, RecursionError) as exc:
        raise MappingError(f"mapping file {p} is not valid TOML: {exc}") from None
    return mapping_from_dict(data, p, commissioning)


def mapping_from_dict(data: Mapping[str, Any], path: Path | None = None, commissioning: bool = False) -> SignalMapping:
    where = f"mapping {path.name if path else '<text>'}"
    base = path.parent if path is not None else Path(".")
    _only(data, {"kind", "dbc", "rate_hz", "listen_only", "read_mapping", "cycles", "joint", "e2e", "trace"}, where)
    kind = data.get("kind")
    if kind not in KINDS:
        raise MappingError(f"{where}: kind: must be one of {list(KINDS)}, got {kind!r}")
    dbc = None
    if kind == "dbc":
        if not isinstance(data.get("dbc"), str):
            raise MappingError(f"{where}: dbc: name the DBC file (path relative to the mapping file)")
        dbc = base / data["dbc"]
    listen_only = _bool(data.get("listen_only", True), f"{where}: listen_only")
    read_mapping = data.get("read_mapping", "eds")
    if read_mapping not in ("eds", "sdo"):
        raise MappingError(f"{where}: read_mapping: eds (from the EDS, nothing sent) or sdo, got {read_mapping!r}")
    if read_mapping == "sdo" and listen_only:
        raise MappingError(f"{where}: read_mapping = \"sdo\" sends SDO requests: set listen_only = false to allow it")
    if read_mapping == "sdo":
        raise MappingError(f"{where}: read_mapping = \"sdo\" is not implemented yet: give the drive's EDS/DCF "
                           "(read_mapping = \"eds\") or write its TPDO mapping as joint.N.tpdo")
    trace = _trace(data.get("trace", {}), f"{where}: trace") if kind == "trace" else None
    joints_table = data.get("joint")
    if not isinstance(joints_table, dict) or not joints_table:
        raise MappingError(f"{where}: joint: add a [joint.N] table for each joint (N = 0, 1, …)")
    joints = {}
    for key, table in joints_table.items():
        number = str(key)
        if not (number.isascii() and number.isdigit() and len(number) <= 3 and int(number) <= MAX_JOINT) \
                or not isinstance(table, dict):
            raise MappingError(f"{where}: joint.{str(key)[:24]}: tables are [joint.N] with N = 0 … {MAX_JOINT}")
        joints[int(key)] = _joint(int(key), table, kind, base, f"{where}: joint.{key}")
    duplicate = duplicate_joint(joints, kind, trace is not None and trace.layout == "long")
    if duplicate:
        raise MappingError(f"{where}: {duplicate}")
    cycles = _cycles(data.get("cycles", {}), kind, joints, f"{where}: cycles", commissioning)
    e2e = tuple(_e2e(t, f"{where}: e2e[{i}]") for i, t in enumerate(_list(data.get("e2e", []), f"{where}: e2e")))
    rate = data.get("rate_hz")
    if rate is not None and not (is_finite_number(rate) and rate > 0):
        raise MappingError(f"{where}: rate_hz: must be > 0, got {rate!r}")
    return SignalMapping(kind, path, joints, cycles, dbc, e2e, listen_only, read_mapping, trace,
                         None if rate is None else float(rate))


# ---------------------------------------------------------------------------------------------- tables
def _joint(joint: int, t: Mapping[str, Any], kind: str, base: Path, where: str) -> JointMapping:
    _only(t, {*QUANTITIES, "reference_torque_nm", "rated_torque_nm", "gear_ratio", "side", "node", "eds",
              "velocity_factor", "tpdo", "key"}, where)
    side = t.get("side", "motor")
    if side not in ("motor", "joint"):
        raise MappingError(f"{where}: side: motor or joint (joint: speeds × gear_ratio, torques / gear_ratio)")
    ratio = t.get("gear_ratio", 1.0)
    if not (within(ratio, GEAR_RATIO) and ratio > 0):
        raise MappingError(f"{where}: gear_ratio: must be > 0, {GEAR_RATIO[0]:g} … {GEAR_RATIO[1]:g}, got {ratio!r}")
    if ("gear_ratio" in t) != (side == "joint"):         # the ratio converts joint-side signals only
        raise MappingError(f"{where}: " + ("gear_ratio: applies to joint-side signals only: add side = \"joint\" (or "
                                           "remove it)" if "gear_ratio" in t else "side = \"joint\": needs gear_ratio"
                                           " (motor turns per joint turn; 1 for a direct drive)"))
    ref, rated = t.get("reference_torque_nm"), t.get("rated_torque_nm")
    for name, value in (("reference_torque_nm", ref), ("rated_torque_nm", rated)):
        if value is not None and not (within(value, TORQUE_NM) and value > 0):
            raise MappingError(f"{where}: {name}: must be > 0 N·m, a robot motor's {TORQUE_NM[0]:g} … "
                               f"{TORQUE_NM[1]:g} N·m, got {value!r}")
    jm = JointMapping(joint=joint, reference_torque_nm=None if ref is None else float(ref),
                      rated_torque_nm=None if rated is None else float(rated), gear_ratio=float(ratio), side=side,
                      key=None if t.get("key") is None else str(t["key"]))
    refs = {}
    for q in QUANTITIES:
        if q in t:
            refs[q] = _signal(t[q], q, kind, jm, f"{where}.{q}")
    if kind == "cia402":
        node = t.get("node")
        if not (isinstance(node, int) and not isinstance(node, bool) and 1 <= node <= 127):
            raise MappingError(f"{where}: node: the drive's CANopen node id 1 … 127, got {node!r}")
        eds = base / t["eds"] if isinstance(t.get("eds"), str) else None
        tpdo = tuple(_tpdo(p, f"{where}.tpdo[{i}]") for i, p in enumerate(_list(t.get("tpdo", []), f"{where}.tpdo")))
        if (eds is None) == (not tpdo):
            raise MappingError(f"{where}: give eds = \"drive.eds\" or the TPDO mapping as "
                               "tpdo = [{cob_id = 0x181, objects = [\"6041\", \"6077\", \"606C\"]}]"
                               + (", not both (which of them the drive sends is unknown)" if tpdo else ""))
        vf = t.get("velocity_factor")
        if vf is not None and not (within(vf, VELOCITY_FACTOR) and vf > 0):
            raise MappingError(f"{where}: velocity_factor: rad/s per velocity unit, > 0, {VELOCITY_FACTOR[0]:g} … "
                               f"{VELOCITY_FACTOR[1]:g}, got {vf!r}")
        jm = JointMapping(**{**jm.__dict__, "node": node, "eds": eds, "tpdo": tpdo,
                             "velocity_factor": None if vf is None else float(vf)})
    elif "speed" not in refs or "torque" not in refs:
        raise MappingError(f"{where}: speed and torque are required (e.g. speed = {{ message = \"…\", "
                           f"signal = \"…\", unit = \"rpm\" }})")
    return JointMapping(**{**jm.__dict__, **refs})


def _signal(t: Any, quantity: str, kind: str, jm: JointMapping, where: str) -> SignalRef:
    if not isinstance(t, dict):
        raise MappingError(f"{where}: an inline table, e.g. {{ message = \"…\", signal = \"…\", unit = \"…\" }}")
    _only(t, {"message", "signal", "column", "index", "subindex", "unit", "scale"}, where)
    unit = str(t.get("unit", _header_unit(t.get("column")) or _DEFAULT_UNIT[quantity]))
    try:
        factor, offset = joint_conversion(jm, quantity, unit, where)
    except UnitError as exc:
        raise MappingError(str(exc)) from None
    scale = t.get("scale", 1.0)
    if not within(scale, SCALE):
        raise MappingError(f"{where}: scale: a non-zero number applied before the unit ({SCALE[0]:g} … "
                           f"{SCALE[1]:g} in size), got {scale!r}")
    ref = SignalRef(message=t.get("message"), signal=t.get("signal"), column=t.get("column"),
                    index=None if t.get("index") is None else _int(t["index"], f"{where}.index", hex_text=True),
                    subindex=_int(t.get("subindex", 0), f"{where}.subindex"), unit=unit,
                    factor=factor * float(scale), offset=offset, unit_stated="unit" in t,
                    scale=None if "scale" not in t else float(scale))
    needed = {"dbc": ("message", "signal"), "trace": ("column",), "cia402": ("index",)}[kind]
    if quantity in ("speed", "torque") and kind == "cia402":
        needed = ()
    missing = [k for k in needed if getattr(ref, k) is None]
    if missing:
        raise MappingError(f"{where}: needs {' and '.join(missing)} for a {kind} mapping")
    return ref


def joint_conversion(jm: JointMapping, quantity: str, unit: str, where: str) -> tuple[float, float]:
    """(factor, offset) from ``unit`` to the agent's unit of ``quantity`` for joint ``jm`` (UnitError)."""
    return conversion(quantity, unit, where, reference_torque_nm=jm.reference_torque_nm,
                      rated_torque_nm=jm.rated_torque_nm, gear_ratio=jm.gear_ratio, joint_side=jm.side == "joint")


def _header_unit(column: Any) -> str | None:
    """The unit a table header states in brackets, e.g. ``"A1 speed [rpm]"`` → ``rpm``."""
    if isinstance(column, str) and column.endswith("]") and "[" in column:
        return column[column.rindex("[") + 1:-1].strip() or None
    return None


_DEFAULT_UNIT = {"speed": "rad/s", "torque": "fraction", "load": "fraction", "temperature": "degC"}


def _cycles(t: Any, kind: str, joints: dict[int, JointMapping], where: str, commissioning: bool) -> CycleMapping:
    if not isinstance(t, dict):
        raise MappingError(f"{where}: must be a table [cycles]")
    _only(t, {"from", "speeds", "reference_joint", "cycle", "segment", "trigger", "value"}, where)
    source = t.get("from", "motion")
    if source not in CYCLE_SOURCES:
        raise MappingError(f"{where}: from: one of {list(CYCLE_SOURCES)}, got {source!r}")
    speeds = tuple(_list(t.get("speeds", []), f"{where}.speeds"))
    if any(not (is_finite_number(v) and 0 < v <= MAX_LEVEL_SPEED) for v in speeds):
        raise MappingError(f"{where}: speeds: positive rad/s up to {MAX_LEVEL_SPEED:g} (motor side), the test "
                           "cycle's levels in order")
    if source in ("motion", "trigger") and not speeds and not commissioning:
        raise MappingError(f"{where}: speeds: cycles found from the {source} need the designed speed levels "
                           "in order (rad/s, motor side); `edge-monitor check-mapping` lists the steady speeds "
                           "it finds")
    ref_joint = t.get("reference_joint", min(joints))
    if not isinstance(ref_joint, int) or isinstance(ref_joint, bool) or ref_joint not in joints:
        raise MappingError(f"{where}: reference_joint: {ref_joint!r} is not a mapped joint {sorted(joints)}")
    probe = JointMapping(joint=-1)
    cyc = CycleMapping(source=source, speeds=tuple(map(float, speeds)), reference_joint=int(ref_joint))
    refs = {}
    for name in ("cycle", "segment", "trigger"):
        if name in t:
            refs[name] = _signal({**t[name], "unit": "degC"} if isinstance(t[name], dict) else t[name],
                                 "temperature", kind, probe, f"{where}.{name}")
    if source == "controller" and ("cycle" not in refs or "segment" not in refs):
        raise MappingError(f"{where}: from = \"controller\" needs cycle and segment signals")
    if source == "trigger" and "trigger" not in refs:
        raise MappingError(f"{where}: from = \"trigger\" needs trigger = {{ … }} (a program number or a "
                           "digital output) and value = the value that marks the test cycle")
    value = t.get("value", 1)
    if not is_finite_number(value):
        raise MappingError(f"{where}: value: a number, got {value!r}")
    return CycleMapping(**{**cyc.__dict__, **refs, "trigger_value": float(value)})


def _e2e(t: Any, where: str) -> E2EMapping:
    if not isinstance(t, dict):
        raise MappingError(f"{where}: [[e2e]] tables with message, profile, …")
    _only(t, {"message", "profile", "counter_signal", "data_id", "data_ids"}, where)
    profile = t.get("profile")
    if profile not in (2, 5):
        raise MappingError(f"{where}: profile: 2 or 5 (AUTOSAR E2E profiles cantools checks), got {profile!r}")
    if not isinstance(t.get("message"), str):
        raise MappingError(f"{where}: message: the protected message's name")
    ids = tuple(_int(v, f"{where}.data_ids") for v in _list(t.get("data_ids", []), f"{where}.data_ids"))
    if profile == 2 and (len(ids) != 16 or not all(0 <= v <= 0xFF for v in ids)):
        raise MappingError(f"{where}: data_ids: profile 2 needs the 16 data IDs 0 … 255 (one per counter value)")
    data_id = None if t.get("data_id") is None else _int(t["data_id"], f"{where}.data_id")
    if profile == 5 and (data_id is None or not 0 <= data_id <= 0xFFFF):
        raise MappingError(f"{where}: data_id: profile 5 needs the message's 16-bit data ID (0 … 65535)")
    return E2EMapping(message=t["message"], profile=profile, counter_signal=t.get("counter_signal"),
                      data_id=data_id, data_ids=ids)


def _trace(t: Any, where: str) -> TraceFormat:
    if not isinstance(t, dict):
        raise MappingError(f"{where}: must be a table [trace]")
    _only(t, {"layout", "separator", "decimal", "time_column", "time_unit", "joint_column", "encoding"}, where)
    fmt = TraceFormat(layout=t.get("layout", "wide"), separator=t.get("separator", ","),
                      decimal=t.get("decimal", "."), time_column=t.get("time_column", "time"),
                      time_unit=t.get("time_unit", "s"), joint_column=t.get("joint_column"),
                      encoding=t.get("encoding", "utf-8"))
    if fmt.layout not in ("wide", "long"):
        raise MappingError(f"{where}: layout: wide or long, got {fmt.layout!r}")
    if fmt.time_unit not in ("s", "ms"):
        raise MappingError(f"{where}: time_unit: s or ms, got {fmt.time_unit!r}")
    if fmt.layout == "long" and not fmt.joint_column:
        raise MappingError(f"{where}: joint_column: a long table needs the column that names the joint")
    if not (isinstance(fmt.separator, str) and len(fmt.separator) == 1 and fmt.separator not in "\r\n\"+-"
            and not fmt.separator.isalnum()) or fmt.decimal not in (".", ",") or fmt.decimal == fmt.separator:
        raise MappingError(f"{where}: separator: one character other than a quote, a line end, a letter, a digit or "
                           "a sign (e.g. \";\", \",\" or a tab); decimal: \".\" or \",\" (not the separator)")
    if not isinstance(fmt.encoding, str) or fmt.encoding.lower().replace("_", "-") not in ENCODINGS:
        raise MappingError(f"{where}: encoding: one of {list(ENCODINGS)} (a trace tool on Windows often writes "
                           f"cp1252), got {fmt.encoding!r}")
    for key in ("time_column", "joint_column"):
        if getattr(fmt, key) is not None and not isinstance(getattr(fmt, key), str):
            raise MappingError(f"{where}: {key}: a column name (text), got {getattr(fmt, key)!r}")
    return fmt


# ---------------------------------------------------------------------------------------------- helpers
def _only(t: Mapping[str, Any], allowed: set[str], where: str) -> None:
    unknown = sorted(set(t) - allowed)
    if unknown:
        raise MappingError(f"{where}: unknown key(s) {unknown}; allowed: {sorted(allowed)}")


def _list(value: Any, where: str) -> list[Any]:
    if not isinstance(value, list):
        raise MappingError(f"{where}: a list [ … ], got {value!r}")
    return value


def _tpdo(p: Any, where: str) -> tuple[int, tuple[str, ...]]:
    """One TPDO written in the mapping: ``{cob_id = 0x181, objects = ["6041", "6077", "606C"]}``."""
    if not isinstance(p, dict):
        raise MappingError(f"{where}: an inline table {{cob_id = 0x181, objects = [\"6041\", \"6077\", \"606C\"]}}")
    cob_id = _int(p.get("cob_id"), f"{where}.cob_id")
    if not 0x001 <= cob_id <= 0x7FF:
        raise MappingError(f"{where}.cob_id: an 11-bit COB-ID (the default TPDOs: 0x181 … 0x57F), got {cob_id:#x}")
    return cob_id, tuple(str(o) for o in _list(p.get("objects", []), f"{where}.objects"))


def _bool(value: Any, where: str) -> bool:
    if not isinstance(value, bool):
        raise MappingError(f"{where}: true or false, got {value!r}")
    return value


def _int(value: Any, where: str, hex_text: bool = False) -> int:
    """An integer; text as Python reads it, or (``hex_text``: a CANopen index) as hex, "2010", "2010h", "0x2010"."""
    if isinstance(value, str):
        try:
            return int(value.strip().removesuffix("h").removesuffix("H"), 16) if hex_text else int(value, 0)
        except ValueError:
            pass
    if isinstance(value, int) and not isinstance(value, bool):
        return value
    raise MappingError(f"{where}: an integer (e.g. 0x2010), got {value!r}")
