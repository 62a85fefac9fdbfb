"""What a mapping file may state and still describe a robot: the ranges of its numbers, and joints that are
distinct (two joints are never one drive, one signal or one column). A value outside is a typo or a wrong
unit that would turn every sample into zero, infinity or nonsense; the mapping loader refuses it, naming
the key (protocol.signal_mapping)."""

from __future__ import annotations

from typing import Any

from protocol.numbers import is_finite_number

#: Motor torques [N·m] (reference T_ref and rated, 6076h): from a small servo's to a large joint's.
TORQUE_NM = (1e-3, 1e5)
#: Gear ratios (joint-side signals are scaled by it).
GEAR_RATIO = (1e-2, 1e4)
#: rad/s per unit of 606Ch (a 32-bit encoder in inc/s: 1.5e-9).
VELOCITY_FACTOR = (1e-12, 1e3)
#: |scale| applied to a signal before its unit.
SCALE = (1e-12, 1e12)
#: Fastest designed test-cycle level [rad/s, motor side] (the agent drops faster samples as implausible).
MAX_LEVEL_SPEED = 2000.0


def within(value: Any, limits: tuple[float, float]) -> bool:
    """``value`` is a finite number and ``limits[0] <= |value| <= limits[1]`` (> 0 for positive ranges)."""
    return is_finite_number(value) and limits[0] <= abs(value) <= limits[1]


def duplicate_joint(joints: dict[int, Any], kind: str, long_table: bool) -> str | None:
    """The first joint that shares its drive (CiA 402 node), its speed signal (DBC message.signal), its
    speed column (a wide table) or its key (a long table) with a joint before it, as a message; None if all
    are distinct."""
    seen: dict[Any, int] = {}
    for j, jm in sorted(joints.items()):
        if kind == "cia402":
            key, what = jm.node, f"node {jm.node}"
        elif kind == "trace" and long_table:
            key = jm.key if jm.key is not None else str(j)
            what = f"key {key!r}"
        else:
            key, what = (jm.speed.describe() if jm.speed is not None else None), f"speed {jm.speed.describe()}"
        if key is not None and key in seen:
            return (f"joint.{j}: {what} is also joint.{seen[key]}'s: two joints cannot be one drive or signal "
                    "(each joint has its own)")
        seen[key] = j
    return None
