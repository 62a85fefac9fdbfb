"""The unit a DBC gives each signal a mapping reads, checked against the mapping's (docs/CONNECTING.md).

cantools decodes a signal into the DBC's unit; the mapping's ``unit`` says which unit that is. When they
disagree the values would be off by a factor, so for each mapped joint signal (speed, torque, load,
temperature):

* the DBC gives no unit (many DBCs omit them): the mapping's unit is taken (one info line per DBC);
* one unit under two spellings (``"N.m"``/``"Nm"``, ``"U/min"``/``"rpm"``): nothing to do;
* the mapping states no unit and the DBC's unit is one the agent converts (``mNm``, ``rpm``, ``deg/s``, ``K``, …):
  the DBC's unit is converted, with an info line;
* the mapping states another unit: refused (:class:`MappingError` naming the signal, both units and the key
  to fix), unless the mapping's ``scale`` converts the one into the other (or, for a unit the agent does not
  know, the mapping's stated ``scale`` says how the values convert);
* the DBC's unit is none of the quantity's and the mapping states neither unit nor scale: refused.
"""

from __future__ import annotations

import logging
import math
from dataclasses import replace

from protocol.bitfields import ResolvedSignal
from protocol.signal_mapping import JointMapping, MappingError, SignalRef, joint_conversion
from protocol.units import RELATIVE_TORQUE_UNITS, UnitError, canonical_unit, same_unit, units_of

log = logging.getLogger(__name__)


def checked_ref(found: ResolvedSignal, ref: SignalRef, jm: JointMapping, quantity: str, where: str) -> SignalRef:
    """``ref`` for the DBC signal ``found`` it names: unchanged, or converting the DBC's unit (see the module
    docstring); MappingError when the units disagree."""
    unit = found.unit
    if not unit or same_unit(unit, ref.unit, quantity):
        return ref
    name = f"{found.message}.{found.bits.name}"
    known = canonical_unit(unit) in units_of(quantity)
    if ref.unit_stated:
        if _scale_converts(unit, ref, quantity) if known else ref.scale is not None:
            log.info("%s: %s is in %r (the DBC's unit); the mapping reads it as %r with scale = %g", where, name,
                     unit, ref.unit, ref.scale)
            return ref
        raise MappingError(_mismatch(where, name, unit, ref, quantity, known))
    if not known:
        raise MappingError(f"{where}: signal {name} is in {unit!r} (the DBC's unit), which is no {quantity} unit "
                           f"the agent converts ({', '.join(sorted(units_of(quantity)))}); the mapping expects "
                           f"{ref.unit!r} (its default): if the signal holds {quantity}, state its unit and scale in "
                           f"{_key(where)} (unit = \"…\", scale = …: value × scale is in that unit), else map "
                           "another signal")
    try:
        factor, offset = joint_conversion(jm, quantity, canonical_unit(unit), where)
    except UnitError as exc:
        raise MappingError(f"{exc} ({name} is in {unit!r}, the DBC's unit)") from None
    log.info("%s: %s is in %r (the DBC's unit; the mapping states none): converted to the agent's unit",
             where, name, unit)
    return replace(ref, unit=canonical_unit(unit), factor=factor * (1.0 if ref.scale is None else ref.scale),
                    offset=offset)


def _key(where: str) -> str:
    """The mapping key of ``where`` ("m.toml: joint.0.torque" → "joint.0.torque")."""
    return where.rsplit(": ", 1)[-1]


def _factors(unit: str, quantity: str) -> tuple[float, float, bool]:
    """(factor, offset, relative) of a known unit of ``quantity`` (relative: a torque of a rating)."""
    value = units_of(quantity)[canonical_unit(unit)]
    factor, offset = value if isinstance(value, tuple) else (value, 0.0)
    relative = quantity in ("torque", "load") and canonical_unit(unit) in RELATIVE_TORQUE_UNITS
    return factor, offset, relative


def _ratio(unit: str, ref: SignalRef, quantity: str) -> float | None:
    """What a value in the DBC's ``unit`` is in the mapping's unit (None: they do not compare)."""
    if canonical_unit(ref.unit) not in units_of(quantity):
        return None
    f_dbc, o_dbc, rel_dbc = _factors(unit, quantity)
    f_map, o_map, rel_map = _factors(ref.unit, quantity)
    return f_dbc / f_map if (rel_dbc, o_dbc) == (rel_map, o_map) else None


def _scale_converts(unit: str, ref: SignalRef, quantity: str) -> bool:
    ratio = _ratio(unit, ref, quantity)
    return ratio is not None and ref.scale is not None and math.isclose(abs(ref.scale), ratio, rel_tol=1e-9)


def _mismatch(where: str, name: str, unit: str, ref: SignalRef, quantity: str, known: bool) -> str:
    ratio = _ratio(unit, ref, quantity) if known else None
    off = ""
    if ratio is not None and ratio != 1.0:
        off = (f": read as {ref.unit} its values would be {max(ratio, 1 / ratio):.4g} times too "
               f"{'large' if ratio < 1 else 'small'}")
    key = _key(where)
    if known:
        fix = (f"set unit = \"{canonical_unit(unit)}\" in {key} (the agent converts it), or if the DBC's unit "
               f"is wrong, scale = … in {key} to say how its values convert")
    else:
        fix = (f"if {unit!r} is another name of {ref.unit}, confirm it with scale = 1 in {key}; else state the "
               f"signal's real unit and scale there")
    stated = f"unit = {ref.unit!r}" + ("" if ref.scale is None else f", scale = {ref.scale:g}")
    return f"{where}: signal {name} is in {unit!r} (the DBC's unit), the mapping says {stated}{off}; {fix}"
