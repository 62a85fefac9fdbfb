"""The DBC description of the frame catalogue: rendered from ``protocol.frames``, loaded with cantools.

The packaged file ``protocol/dbc/robot_joints.dbc`` is ``render_dbc()`` (a test keeps them equal).
Torques travel as fractions of each joint's reference (maximum) torque; the DBC states them in Nm
with factor = LSB fraction × the message's ``ReferenceTorqueNm`` attribute. The packaged file uses
the nominal ``NOMINAL_REFERENCE_TORQUE_NM`` for every joint; for a real robot render one with its
joints' maximum torques (the wire format does not change)::

    python -m protocol.dbc --reference-torque 2500,2500,1200,400,400,200 --out robot.dbc

Attributes (docs/PROTOCOL.md "DBC"): network ``BusType``/``DBName``/``Baudrate``; message
``GenMsgSendType``/``GenMsgCycleTime``, ``E2EProfile``/``E2EDataID``, ``ReferenceTorqueNm``;
signal ``SignalRole`` (E2E_CRC, E2E_ALIVE_COUNTER, RESERVED, DATA).
"""

from __future__ import annotations

import argparse
import sys
from importlib import resources
from pathlib import Path
from typing import Sequence

import cantools

from protocol import frames as F

DBC_RESOURCE = "robot_joints.dbc"
DATABASE_NAME = "robot_joints"
#: Reference torque [Nm] the packaged DBC states for every joint (the simulator is dimensionless).
NOMINAL_REFERENCE_TORQUE_NM = 100.0
#: Nominal bit rate: frames of one controller tick are one 8-byte frame time (111 µs) apart.
BAUDRATE = 1_000_000
#: Cycle times [ms] at the controller's default 500 Hz tick (status every 10th tick).
CYCLE_TIME_MS = {F.FrameKind.MOTOR_STATE: 2, F.FrameKind.CONTROLLER_STATUS: 20, F.FrameKind.JOINT_STATUS: 20}
E2E_PROFILE = "CRC8H2F_DataID16"
#: Vector's GenMsgSendType enumeration (index 0 = Cyclic), as CANdb++ templates define it.
SEND_TYPES = ("Cyclic", "NotUsed", "NotUsed", "NotUsed", "NotUsed", "NotUsed", "NotUsed", "IfActive",
              "NoMsgSendType", "NotUsed")

_NODES = {
    "Controller": "robot controller (or sim-controller): sends every frame of the catalogue",
    "Monitor": "edge condition monitor (edge-monitor): receives only",
}
_MESSAGE_COMMENTS = {
    F.FrameKind.MOTOR_STATE: "motor state of joint {joint}, every controller tick",
    F.FrameKind.CONTROLLER_STATUS: "controller status, every 10th controller tick",
    F.FrameKind.JOINT_STATUS: "status of joint {joint}, with each ControllerStatus",
}
_E2E = ("E2E: CRC-8H2F (poly 0x2F, init 0xFF, xorout 0xFF) over data ID 0x{data_id:04X} (low byte, "
        "high byte) + bytes 1..7, in byte 0; alive counter in signal {counter}")
_TORQUE = ("wire value is a fraction of the joint's reference (maximum) torque, 5e-05 per LSB; "
           "the Nm factor is 5e-05 x ReferenceTorqueNm of this message")
_SIGNAL_COMMENTS = {
    "crc": "E2E CRC-8H2F (poly 0x2F, init 0xFF, xorout 0xFF) over data ID (low, high) + bytes 1..7",
    "counter": "E2E alive counter 0..15, +1 per frame",
    "reserved": "always 0",
    "reserved2": "always 0",
    "mode": "controller mode",
    "cycle": "test-cycle number (wraps at 65536)",
    "segment": "0 none/transition, 1..64 friction speed level k (1-based), 200 production motion",
    "load_estimate": "controller's estimate of the manipulation load torque; " + _TORQUE,
    "load_std": "standard deviation of load_estimate; wire value is a fraction of the joint's reference "
                "torque, 0.002 per LSB; the Nm factor is 0.002 x ReferenceTorqueNm of this message",
    "motor_temperature": "motor winding temperature (not the lubricant)",
    "torque": "motor torque; " + _TORQUE,
    "speed": "motor speed (motor side)",
    "position": "motor angle modulo one revolution",
}
_TICK_COMMENTS = {
    F.FrameKind.MOTOR_STATE: "E2E alive counter = controller tick mod 256 (also the sample counter)",
    F.FrameKind.CONTROLLER_STATUS: "controller tick of this frame (wraps at 2^24)",
}
_NAMESPACE = ("CM_", "BA_DEF_", "BA_", "VAL_", "BA_DEF_DEF_", "VAL_TABLE_", "SIG_VALTYPE_", "BO_TX_BU_")


def _number(value: float) -> str:
    """Shortest text that reads back as ``value`` (integers without a decimal point)."""
    if float(value).is_integer() and abs(value) < 1e15:
        return str(int(value))
    return repr(float(value))


def _round15(value: float) -> float:
    """``value`` to 15 significant digits: 5e-05 × 100 is written 0.005, not 0.005000000000000001."""
    return float(f"{value:.15g}")


def dbc_factor(signal: F.Signal, reference_torque_nm: float) -> float:
    """The DBC factor of ``signal`` for a joint with this reference torque [Nm]."""
    return _round15(signal.scale * reference_torque_nm) if signal.per_reference_torque else signal.scale


def _choices(signal: F.Signal) -> dict[int, str]:
    if signal.name == "mode":
        return {int(mode): mode.name for mode in F.Mode}
    if signal.name == "segment":
        levels = {k: f"SPEED_LEVEL_{k}" for k in range(1, F.MAX_SPEED_LEVELS + 1)}
        return {F.SEGMENT_NONE: "NONE", **levels, F.SEGMENT_PRODUCTION: "PRODUCTION"}
    return {}


def _signal_line(signal: F.Signal, factor: float) -> str:
    if signal.role is F.SignalRole.RESERVED:
        low = high = 0.0
    elif signal.name == "mode":                  # values above the last Mode are rejected (BAD_VALUE)
        low, high = 0.0, float(max(F.Mode))
    else:
        low, high = signal.raw_min * factor, signal.raw_max * factor
    sign = "-" if signal.signed else "+"
    return (f" SG_ {signal.name} : {signal.start}|{signal.length}@1{sign} ({_number(factor)},"
            f"{_number(signal.offset)}) [{_number(_round15(low))}|{_number(_round15(high))}] "
            f'"{signal.unit}" Monitor')


def _check_references(reference_torque_nm: float | Sequence[float]) -> list[float]:
    """Per-joint reference torques: one value for all joints, or joints 0.. in order (joints not
    given keep ``NOMINAL_REFERENCE_TORQUE_NM``)."""
    values = [reference_torque_nm] * F.MAX_JOINTS if isinstance(reference_torque_nm, (int, float)) \
        else list(reference_torque_nm)
    if not 1 <= len(values) <= F.MAX_JOINTS or not all(
            isinstance(v, (int, float)) and 0 < v < 1e5 for v in values):
        raise ValueError(f"need 1 to {F.MAX_JOINTS} reference torques in Nm, each > 0 and < 100000; "
                         f"got {reference_torque_nm!r}")
    return [float(v) for v in values] + [NOMINAL_REFERENCE_TORQUE_NM] * (F.MAX_JOINTS - len(values))


def render_dbc(reference_torque_nm: float | Sequence[float] = NOMINAL_REFERENCE_TORQUE_NM) -> str:
    """DBC text of the catalogue; ``reference_torque_nm``: one value for all joints or one per joint."""
    references = _check_references(reference_torque_nm)
    lines = [f'VERSION "{DATABASE_NAME} 2"', "", "", "NS_ :", *(f"\t{k}" for k in _NAMESPACE), "",
             "BS_:", "", "BU_: " + " ".join(_NODES), "", ""]
    for frame in F.CATALOGUE.values():
        lines.append(f"BO_ {frame.arbitration_id} {frame.name}: {F.FRAME_LENGTH} Controller")
        factors = _factors(frame, references)
        lines += [_signal_line(s, factors[s.name]) for s in F.SIGNALS_BY_KIND[frame.kind]]
        lines.append("")
    lines += ["", *_comments(), *_attribute_definitions(), *_attributes(references), *_value_tables()]
    return "\n".join(lines) + "\n"


def _factors(frame: F.FrameType, references: list[float]) -> dict[str, float]:
    reference = references[frame.joint] if frame.joint >= 0 else 0.0
    return {s.name: dbc_factor(s, reference) for s in F.SIGNALS_BY_KIND[frame.kind]}


def _counter_name(kind: F.FrameKind) -> str:
    return next(s.name for s in F.SIGNALS_BY_KIND[kind] if s.role is F.SignalRole.E2E_ALIVE_COUNTER)


def _comments() -> list[str]:
    lines = ['CM_ "Robot joint condition-monitoring frames (joint-wear-monitor); layout in docs/PROTOCOL.md. '
             'Classical CAN, 11-bit IDs, little-endian (Intel) signals, E2E-protected (E2EProfile, E2EDataID, '
             'SignalRole attributes).";']
    lines += [f'CM_ BU_ {node} "{text}";' for node, text in _NODES.items()]
    for frame in F.CATALOGUE.values():
        text = _MESSAGE_COMMENTS[frame.kind].format(joint=frame.joint)
        e2e = _E2E.format(data_id=frame.data_id, counter=_counter_name(frame.kind))
        lines.append(f'CM_ BO_ {frame.arbitration_id} "{frame.name}: {text}. {e2e}";')
    for frame in F.CATALOGUE.values():
        for signal in F.SIGNALS_BY_KIND[frame.kind]:
            text = _TICK_COMMENTS[frame.kind] if signal.name == "tick" else _SIGNAL_COMMENTS[signal.name]
            lines.append(f'CM_ SG_ {frame.arbitration_id} {signal.name} "{text}";')
    return lines


def _enum(values: Sequence[str]) -> str:
    return ",".join(f'"{v}"' for v in values)


def _attribute_definitions() -> list[str]:
    roles = [role.name for role in F.SignalRole]
    return [
        'BA_DEF_  "BusType" STRING ;',
        'BA_DEF_  "DBName" STRING ;',
        f'BA_DEF_  "Baudrate" INT 0 {BAUDRATE};',
        f'BA_DEF_ BO_  "GenMsgSendType" ENUM  {_enum(SEND_TYPES)};',
        'BA_DEF_ BO_  "GenMsgCycleTime" INT 0 65535;',
        f'BA_DEF_ BO_  "E2EProfile" ENUM  {_enum(("None", E2E_PROFILE))};',
        'BA_DEF_ BO_  "E2EDataID" HEX 0 65535;',
        'BA_DEF_ BO_  "ReferenceTorqueNm" FLOAT 0 100000;',
        f'BA_DEF_ SG_  "SignalRole" ENUM  {_enum(roles)};',
        'BA_DEF_DEF_  "BusType" "CAN";',
        'BA_DEF_DEF_  "DBName" "";',
        f'BA_DEF_DEF_  "Baudrate" {BAUDRATE};',
        'BA_DEF_DEF_  "GenMsgSendType" "NoMsgSendType";',
        'BA_DEF_DEF_  "GenMsgCycleTime" 0;',
        'BA_DEF_DEF_  "E2EProfile" "None";',
        'BA_DEF_DEF_  "E2EDataID" 0;',
        'BA_DEF_DEF_  "ReferenceTorqueNm" 0;',
        f'BA_DEF_DEF_  "SignalRole" "{F.SignalRole.DATA.name}";',
    ]


def _attributes(references: list[float]) -> list[str]:
    lines = ['BA_ "BusType" "CAN";', f'BA_ "DBName" "{DATABASE_NAME}";', f'BA_ "Baudrate" {BAUDRATE};']
    for frame in F.CATALOGUE.values():
        message = f"BO_ {frame.arbitration_id}"
        lines += [f'BA_ "GenMsgSendType" {message} {SEND_TYPES.index("Cyclic")};',
                  f'BA_ "GenMsgCycleTime" {message} {CYCLE_TIME_MS[frame.kind]};',
                  f'BA_ "E2EProfile" {message} 1;',
                  f'BA_ "E2EDataID" {message} {frame.data_id};']
        if frame.joint >= 0:
            lines.append(f'BA_ "ReferenceTorqueNm" {message} {_number(references[frame.joint])};')
    for frame in F.CATALOGUE.values():
        lines += [f'BA_ "SignalRole" SG_ {frame.arbitration_id} {s.name} {int(s.role)};'
                  for s in F.SIGNALS_BY_KIND[frame.kind] if s.role is not F.SignalRole.DATA]
    return lines


def _value_tables() -> list[str]:
    lines = []
    for frame in F.CATALOGUE.values():
        for signal in F.SIGNALS_BY_KIND[frame.kind]:
            if choices := _choices(signal):
                pairs = " ".join(f'{value} "{name}"' for value, name in choices.items())
                lines.append(f"VAL_ {frame.arbitration_id} {signal.name} {pairs} ;")
    return lines


def dbc_text() -> str:
    """Text of the packaged DBC file."""
    try:
        return resources.files("protocol").joinpath("dbc", DBC_RESOURCE).read_text(encoding="utf-8")
    except (NotADirectoryError, FileNotFoundError, TypeError):
        # setuptools' editable finder can present `protocol` as a namespace package whose path
        # holds a non-directory placeholder, which importlib.resources (3.11) rejects.
        return (Path(__file__).resolve().parent / "dbc" / DBC_RESOURCE).read_text(encoding="utf-8")


def load_database(text: str | None = None) -> cantools.database.can.Database:
    """The frame catalogue as a cantools database (strict: overlapping/oversized signals raise);
    ``text``: a DBC from :func:`render_dbc`, default the packaged file."""
    db = cantools.database.load_string(dbc_text() if text is None else text, database_format="dbc", strict=True)
    assert isinstance(db, cantools.database.can.Database)    # database_format="dbc" gives a CAN database
    return db


def reference_torque_nm(message: cantools.database.can.Message) -> float | None:
    """The ``ReferenceTorqueNm`` attribute of a MotorState/JointStatus message (None for others)."""
    attribute = message.dbc.attributes.get("ReferenceTorqueNm") if message.dbc else None
    return None if attribute is None else float(attribute.value)


def main(argv: Sequence[str] | None = None) -> int:
    """``python -m protocol.dbc``: write the DBC for a robot's joint reference torques."""
    parser = argparse.ArgumentParser(prog="python -m protocol.dbc", description=__doc__.splitlines()[0])
    parser.add_argument("--reference-torque", default=str(NOMINAL_REFERENCE_TORQUE_NM), metavar="NM[,NM...]",
                        help="reference (maximum) torque of each joint in Nm: one value for all joints, or "
                             "comma-separated values for joints 0, 1, ... (joints not given: "
                             f"{NOMINAL_REFERENCE_TORQUE_NM:g}; default %(default)s)")
    parser.add_argument("--out", help="output file (default: standard output)")
    args = parser.parse_args(argv)
    try:
        values = [float(v) for v in args.reference_torque.split(",")]
        text = render_dbc(values[0] if len(values) == 1 else values)
    except ValueError as error:
        parser.error(f"--reference-torque {args.reference_torque}: {error}")
    if args.out:
        Path(args.out).write_text(text, encoding="utf-8")
    else:
        sys.stdout.write(text)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
