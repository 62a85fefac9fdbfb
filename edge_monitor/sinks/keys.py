"""The Zenoh key space of the agent (docs/OUTPUTS.md), built and parsed in one place.

    edge/<robot>/<joint>/{symptom,alarm,advisory,friction,state,maintenance,acknowledge}
    edge/<robot>/agent/health          edge/<robot>/agent (liveliness token)
"""

from __future__ import annotations

import re
from dataclasses import dataclass

SYMPTOM = "symptom"
ALARM = "alarm"
ADVISORY = "advisory"
FRICTION = "friction"
HEALTH = "health"
STATE = "state"
MAINTENANCE = "maintenance"
ACKNOWLEDGE = "acknowledge"
KINDS = (SYMPTOM, ALARM, ADVISORY, FRICTION, HEALTH)
AGENT = "agent"
PREFIX = "edge"
#: A robot name is one key segment: no key-expression syntax (``/ * $ ? #``), no spaces.
_ROBOT = re.compile(r"^[A-Za-z0-9_.-]{1,64}$")
#: Names no robot may have: ``edge/history/**`` is the historian's queryable.
RESERVED_ROBOTS = ("history",)


def check_robot_name(robot: str) -> str:
    """``robot`` if it can be one key segment and is not reserved, else ``ValueError`` saying how to fix it."""
    if not isinstance(robot, str) or not _ROBOT.match(robot):
        raise ValueError(f"robot name {robot!r} must be 1 … 64 letters, digits, '_', '-' or '.'; "
                         "fix the robot name in the config")
    if robot in RESERVED_ROBOTS:
        raise ValueError(f"robot name {robot!r} is reserved (edge/{robot}/** is the historian's queryable); "
                         "choose another robot name in the config")
    return robot


def joint_key(robot: str, joint: int | str, kind: str) -> str:
    """``edge/<robot>/<joint>/<kind>`` (``joint`` may be ``*`` in a key expression)."""
    return f"{PREFIX}/{robot}/{joint}/{kind}"


def agent_key(robot: str, kind: str | None = None) -> str:
    """``edge/<robot>/agent`` (liveliness) or ``edge/<robot>/agent/<kind>``."""
    return f"{PREFIX}/{robot}/{AGENT}" + ("" if kind is None else f"/{kind}")


@dataclass(frozen=True)
class KeyParts:
    robot: str
    joint: int | None          # None for agent-level keys
    kind: str


def parse_key(key: str) -> KeyParts | None:
    """``edge/<robot>/<joint|agent>/<kind>`` → its parts; None for any other key (wrong prefix or
    depth, a joint that is not a small non-negative integer written canonically, a robot name that is
    not one plain segment — wildcards never parse)."""
    parts = str(key).split("/")
    if len(parts) != 4 or parts[0] != PREFIX or not _ROBOT.match(parts[1]) or not parts[3]:
        return None
    if parts[2] == AGENT:
        return KeyParts(parts[1], None, parts[3])
    if not parts[2].isdigit() or len(parts[2]) > 3 or str(int(parts[2])) != parts[2]:   # canonical: no "01"
        return None
    return KeyParts(parts[1], int(parts[2]), parts[3])


def robot_of(key: str) -> str | None:
    """The robot of any ``edge/<robot>/…`` key (e.g. a liveliness token), None for other keys."""
    parts = str(key).split("/")
    return parts[1] if len(parts) >= 3 and parts[0] == PREFIX and _ROBOT.match(parts[1]) else None
