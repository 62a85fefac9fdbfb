"""Units a controller's signals come in, and their factors to the agent's units.

The agent works in motor-side speed [rad/s], torque as a fraction of the joint's reference (maximum)
motor torque T_ref (docs/PROTOCOL.md, "Torque unit") and temperature [°C]. A mapping names each
signal's unit; :func:`speed_factor` and :func:`torque_factor` give the multiplier to the agent's unit,
including the gear ratio for joint-side signals. Unknown or mismatched units raise :class:`UnitError`
naming the field and the units that would work.
"""

from __future__ import annotations

import math

#: Speed units → rad/s.
SPEED_UNITS: dict[str, float] = {
    "rad/s": 1.0, "rpm": 2.0 * math.pi / 60.0, "1/min": 2.0 * math.pi / 60.0, "rev/s": 2.0 * math.pi,
    "deg/s": math.pi / 180.0, "mrad/s": 1e-3,
}
#: Torque units → N·m ("fraction" and the relative units are handled by :func:`torque_factor`).
TORQUE_UNITS_NM: dict[str, float] = {"Nm": 1.0, "N.m": 1.0, "N·m": 1.0, "mNm": 1e-3, "kNm": 1e3}
#: Torque units relative to a rating: fraction of T_ref, or per cent / per mille of the rated torque.
RELATIVE_TORQUE_UNITS: dict[str, float] = {"fraction": 1.0, "%": 1e-2, "permille": 1e-3, "‰": 1e-3}
#: Temperature units → (factor, offset) to °C.
TEMPERATURE_UNITS: dict[str, tuple[float, float]] = {"degC": (1.0, 0.0), "°C": (1.0, 0.0), "C": (1.0, 0.0),
                                                     "K": (1.0, -273.15)}


#: Other spellings of those units, as DBCs write them.
UNIT_ALIASES: dict[str, str] = {
    "RPM": "rpm", "Rpm": "rpm", "U/min": "rpm", "rev/min": "rpm", "r/min": "rpm",
    "rad/sec": "rad/s", "°/s": "deg/s", "deg/sec": "deg/s",
    "N*m": "Nm", "NM": "Nm", "mN*m": "mNm", "mN.m": "mNm", "mN·m": "mNm", "Nmm": "mNm", "N*mm": "mNm", "N.mm": "mNm",
    "kN*m": "kNm", "kN.m": "kNm", "percent": "%", "deg C": "degC", "degreeC": "degC", "Cel": "degC",
}


def canonical_unit(unit: str) -> str:
    """``unit`` as the tables above spell it (``"U/min"`` → ``"rpm"``); unknown units unchanged."""
    unit = unit.strip()
    return UNIT_ALIASES.get(unit, unit)


def units_of(quantity: str) -> dict[str, float | tuple[float, float]]:
    """The units of ``quantity`` ("speed", "torque", "load", "temperature") the agent converts."""
    return {unit: value for table in _tables(quantity) for unit, value in table.items()}


def _tables(quantity: str) -> list[dict]:
    """The unit tables of ``quantity``: torque's absolute and relative units apart (1 Nm is no fraction)."""
    if quantity == "speed":
        return [SPEED_UNITS]
    if quantity in ("torque", "load"):
        return [TORQUE_UNITS_NM, RELATIVE_TORQUE_UNITS]
    return [TEMPERATURE_UNITS]


def same_unit(a: str, b: str, quantity: str) -> bool:
    """Whether ``a`` and ``b`` are one unit of ``quantity`` (``"N.m"`` and ``"Nm"``, ``"1/min"`` and ``"RPM"``)."""
    a, b = canonical_unit(a), canonical_unit(b)
    return a == b or any(a in table and b in table and table[a] == table[b] for table in _tables(quantity))


class UnitError(ValueError):
    """A unit that does not convert; the message names the field and the units that do."""


def speed_factor(unit: str, where: str, gear_ratio: float = 1.0, joint_side: bool = False) -> float:
    """Multiplier from ``unit`` to motor-side rad/s (joint-side speeds are multiplied by the gear ratio)."""
    if unit not in SPEED_UNITS:
        raise UnitError(f"{where}: speed unit {unit!r} does not convert to rad/s; use one of {sorted(SPEED_UNITS)}")
    return SPEED_UNITS[unit] * (gear_ratio if joint_side else 1.0)


def torque_factor(unit: str, where: str, reference_torque_nm: float | None, rated_torque_nm: float | None = None,
                  gear_ratio: float = 1.0, joint_side: bool = False) -> float:
    """Multiplier from ``unit`` to a fraction of the motor's reference torque T_ref.

    Absolute units need ``reference_torque_nm``; per cent / per mille are of the rated torque
    (``rated_torque_nm``, e.g. CiA 402 object 6076h) and also need T_ref; ``fraction`` is already ours.
    Joint-side torques are divided by the gear ratio first."""
    side = 1.0 / gear_ratio if joint_side else 1.0
    if unit == "fraction":
        return 1.0
    if unit in RELATIVE_TORQUE_UNITS:
        if rated_torque_nm is None or reference_torque_nm is None:
            raise UnitError(f"{where}: torque in {unit} of the rated torque needs rated_torque_nm and "
                            "reference_torque_nm (the motor's maximum torque T_ref)")
        return RELATIVE_TORQUE_UNITS[unit] * rated_torque_nm / reference_torque_nm * side
    if unit in TORQUE_UNITS_NM:
        if reference_torque_nm is None:
            raise UnitError(f"{where}: torque in {unit} needs reference_torque_nm (the motor's maximum torque "
                            "T_ref in N·m), which scales it to the agent's fraction of T_ref")
        return TORQUE_UNITS_NM[unit] / reference_torque_nm * side
    known = sorted([*TORQUE_UNITS_NM, *RELATIVE_TORQUE_UNITS])
    raise UnitError(f"{where}: torque unit {unit!r} does not convert; use one of {known}")


def temperature_conversion(unit: str, where: str) -> tuple[float, float]:
    """(factor, offset): °C = value · factor + offset."""
    if unit not in TEMPERATURE_UNITS:
        raise UnitError(f"{where}: temperature unit {unit!r} does not convert to °C; "
                        f"use one of {sorted(TEMPERATURE_UNITS)}")
    return TEMPERATURE_UNITS[unit]


def conversion(quantity: str, unit: str, where: str, *, reference_torque_nm: float | None = None,
               rated_torque_nm: float | None = None, gear_ratio: float = 1.0,
               joint_side: bool = False) -> tuple[float, float]:
    """(factor, offset) from ``unit`` to the agent's unit of ``quantity`` (speed, torque, load, temperature)."""
    if quantity == "speed":
        return speed_factor(unit, where, gear_ratio, joint_side), 0.0
    if quantity in ("torque", "load"):
        return torque_factor(unit, where, reference_torque_nm, rated_torque_nm, gear_ratio, joint_side), 0.0
    return temperature_conversion(unit, where)
