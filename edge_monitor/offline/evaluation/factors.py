"""The factors of a detector evaluation and their coded levels.

A factor z is the fault (wear on the monitored joint) or a disturbance. Each has a natural range
``[low, high]`` mapped linearly onto the coded levels −2 … 2 (coded 0 = the centre of the range,
one coded unit = (high − low)/4). What a factor sets in the simulator (:class:`SimConfig`) for one
design point, fixed for every cycle of that point:

=================  ==========================================  ==============  ===============
name               what it sets                                default range   supported
=================  ==========================================  ==============  ===============
``wear``           wear ϖ of the monitored joint (the fault)    0 … 50          0 … 100
``wear_other``     wear ϖ of every other joint                  0 … 50          0 … 100
``temperature``    lubricant temperature [°C] (all joints)      30 … 70         30 … 80
``p2p_delay``      production point-to-point delay [ms]         25 … 75         0 … 10000
``payload_error``  payload mass error of the controller [%]     −10 … 10        −50 … 50
``load``           manipulation load torque |τl| (fraction)     0.3 … 0.7       0 … 0.75
=================  ==========================================  ==============  ===============

A factor that is not in the design is held at the centre of its range, except ``load``, which then
keeps the simulator's per-cycle draw |τl| ~ U(0.3, 0.7) (the default robot's load spread). The
supported ranges are where the simulator's friction model holds (temperature: identified on 35 … 80,
used on 30 … 80 °C; |τl| ≤ 0.75) or what its configuration accepts.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Mapping, Sequence

import numpy as np
from numpy.typing import ArrayLike, NDArray

from sim_controller.wear_scenarios import WearProfile

#: Coded levels span −2 … 2.
CODED_MIN, CODED_MAX = -2.0, 2.0


class FactorError(ValueError):
    """Unknown factor name or a range the simulator does not support; the message says which."""


@dataclass(frozen=True)
class Factor:
    """One factor: natural range ``low … high`` (coded −2 … 2) within ``supported``; ``unit`` for reports."""

    name: str
    label: str
    unit: str
    low: float
    high: float
    supported: tuple[float, float]
    held_at_centre: bool = True

    def __post_init__(self) -> None:
        lo, hi = self.supported
        if not (np.isfinite(self.low) and np.isfinite(self.high) and self.low < self.high):
            raise FactorError(f"{self.name}: need LOW < HIGH, got {self.low:g}:{self.high:g}")
        if self.low < lo or self.high > hi:
            raise FactorError(f"{self.name}: range {self.low:g}:{self.high:g} {self.unit} is outside what the "
                              f"simulator supports ({lo:g} … {hi:g} {self.unit})")

    @property
    def centre(self) -> float:
        return 0.5 * (self.low + self.high)

    @property
    def unit_step(self) -> float:
        """Natural size of one coded unit."""
        return (self.high - self.low) / (CODED_MAX - CODED_MIN)

    def natural(self, coded: ArrayLike) -> NDArray[np.float64]:
        """Coded level(s) → natural value(s)."""
        return self.centre + np.asarray(coded, dtype=float) * self.unit_step

    def coded(self, natural: ArrayLike) -> NDArray[np.float64]:
        """Natural value(s) → coded level(s)."""
        return (np.asarray(natural, dtype=float) - self.centre) / self.unit_step


#: Every factor the simulator supports, with its default range (see the module docstring).
FACTORS: dict[str, Factor] = {f.name: f for f in (
    Factor("wear", "wear of the monitored joint (fault)", "", 0.0, 50.0, (0.0, 100.0)),
    Factor("wear_other", "wear of the other joints", "", 0.0, 50.0, (0.0, 100.0)),
    Factor("temperature", "lubricant temperature", "°C", 30.0, 70.0, (30.0, 80.0)),
    Factor("p2p_delay", "point-to-point delay", "ms", 25.0, 75.0, (0.0, 10_000.0)),
    Factor("payload_error", "payload mass error", "%", -10.0, 10.0, (-50.0, 50.0)),
    Factor("load", "load torque |τl|", "", 0.3, 0.7, (0.0, 0.75), held_at_centre=False),
)}
#: The fault factor: always the first factor of a design.
FAULT = "wear"
#: Factors of the default (full) evaluation: the fault and five disturbances → the 45-run design.
DEFAULT_FACTORS: tuple[str, ...] = ("wear", "wear_other", "temperature", "p2p_delay", "payload_error", "load")
#: Factors of ``--quick``.
QUICK_FACTORS: tuple[str, ...] = ("wear", "temperature", "payload_error")


def select_factors(names: Sequence[str], ranges: Mapping[str, tuple[float, float]] | None = None) -> list[Factor]:
    """The factors named (fault first, no duplicates), with ``ranges`` overriding default ranges."""
    ranges = dict(ranges or {})
    unknown = [n for n in list(names) + list(ranges) if n not in FACTORS]
    if unknown:
        raise FactorError(f"unknown factor {unknown[0]!r}; known factors: {', '.join(FACTORS)}")
    if len(set(names)) != len(names):
        raise FactorError(f"factor names repeat: {', '.join(names)}")
    if FAULT not in names:
        raise FactorError(f"the factors must include the fault {FAULT!r}")
    stray = [n for n in ranges if n not in names]
    if stray:
        raise FactorError(f"--range {stray[0]}: not a factor of this design ({', '.join(names)})")
    ordered = [FAULT] + [n for n in names if n != FAULT]
    out = []
    for n in ordered:
        base = FACTORS[n]
        lo, hi = ranges.get(n, (base.low, base.high))
        out.append(Factor(base.name, base.label, base.unit, float(lo), float(hi), base.supported, base.held_at_centre))
    return out


def parse_range_option(text: str) -> tuple[str, tuple[float, float]]:
    """``NAME=LOW:HIGH`` → (name, (low, high)); :class:`FactorError` when malformed."""
    name, sep, rest = text.partition("=")
    parts = rest.split(":")
    if not sep or len(parts) != 2:
        raise FactorError(f"--range expects NAME=LOW:HIGH, got {text!r}")
    try:
        low, high = float(parts[0]), float(parts[1])
    except ValueError:
        raise FactorError(f"--range {text!r}: LOW and HIGH must be numbers") from None
    return name.strip(), (low, high)


def sim_settings(factors: Sequence[Factor], coded: ArrayLike, joint: int, joints: int) -> dict[str, Any]:
    """``SimConfig`` keyword arguments for one design point (``coded``: one level per factor; factors
    missing from the design are held as the module docstring says)."""
    levels = np.asarray(coded, dtype=float)
    value = {f.name: float(f.natural(c)) for f, c in zip(factors, levels)}
    for name, base in FACTORS.items():
        if name not in value and base.held_at_centre:
            value[name] = base.centre
    wear = [value["wear"] if j == joint else value["wear_other"] for j in range(joints)]
    out: dict[str, Any] = {
        "wear": tuple(WearProfile(initial=w) for w in wear),
        "temperature_range": (value["temperature"],) * 2,
        "p2p_delay": (value["p2p_delay"] / 1000.0,) * 2,
        "payload_error": value["payload_error"] / 100.0,
    }
    if "load" in value:
        out["load_range"] = (value["load"],) * 2
    return out
