"""Checks of a saved agent state before any of it is adopted (the state file is untrusted input).

Two layers. :func:`validate_state` checks the whole file against a schema with bounds: the top-level
sections and their types, the robot it belongs to, cycle numbers within :data:`MAX_CYCLE`, published
cycles only with the cycle numbering they came from, joint indices the agent may monitor, and — over
every value in the tree — no NaN or infinity written as a number, no number beyond :data:`MAX_MAGNITUDE`,
no list longer than :data:`MAX_LIST`, no nesting deeper than :data:`MAX_DEPTH`. A failure there rejects
the file (the agent moves it aside and relearns). The component layer is each model's own
``from_state``, which checks its sizes against the same bounds as the config (KDE grid, GLR window)
and its array shapes; a joint whose models fail there is relearned alone (:meth:`edge_monitor.pipeline.agent.Agent`).
"""

from __future__ import annotations

import logging
import math
from typing import Any

from edge_monitor.errors import StateError

log = logging.getLogger(__name__)

#: Largest cycle number a state may hold (unwrapped 16-bit counter; 2⁴⁰ is 10⁷ years at 300 a day).
MAX_CYCLE = 2 ** 40
#: Largest magnitude of any number in a state (sample counts and sums stay far below).
MAX_MAGNITUDE = 1e15
#: Longest list in a state [elements] (the largest, a KDE grid, has at most 65 536).
MAX_LIST = 1 << 17
#: Deepest nesting of a state.
MAX_DEPTH = 32
#: Joint indices a state may name (as the config's ``joints``).
MAX_JOINT = 64
#: Longest string [characters].
MAX_STRING = 4096

_SECTIONS: dict[str, type | tuple[type, ...]] = {
    "version": int, "robot": str, "last_emitted": dict, "ingest": (dict, type(None)), "joints": dict,
    "cycle_rate": dict}


def validate_state(state: Any, robot: str, joints: tuple[int, ...] | None = None) -> dict[str, Any]:
    """``state`` if it is a plausible state of ``robot`` (monitoring ``joints``, None: any), else
    :class:`StateError` naming the first problem found and where."""
    if not isinstance(state, dict):
        raise StateError(f"the state is a JSON {type(state).__name__}, not an object")
    for key, kind in _SECTIONS.items():
        if key in state and not isinstance(state[key], kind):
            raise StateError(f"'{key}' is a {type(state[key]).__name__}")
    _check_tree(state, "state", 0)
    saved_robot = state.get("robot")
    if saved_robot is not None and saved_robot != robot:
        raise StateError(f"it belongs to robot {saved_robot!r}, this agent monitors robot {robot!r}")
    _drop_unconfigured(state, joints)
    for joint, cycle in state.get("last_emitted", {}).items():
        _check_joint(joint, "last_emitted")
        if isinstance(cycle, bool) or not isinstance(cycle, int) or not 0 <= cycle <= MAX_CYCLE:
            raise StateError(f"last_emitted[{joint}] = {cycle!r} is not a cycle number 0 … {MAX_CYCLE}")
    for key, value in (state.get("ingest") or {}).items():
        if value is not None and (isinstance(value, bool) or not isinstance(value, int) or abs(value) > MAX_CYCLE):
            raise StateError(f"ingest.{key} = {value!r} is not a counter within ±{MAX_CYCLE}")
    _check_numbering(state)
    for joint, section in state.get("joints", {}).items():
        _check_joint(joint, "joints")
        if not isinstance(section, dict):
            raise StateError(f"joints[{joint}] is a {type(section).__name__}, not an object")
    return state


def _check_numbering(state: dict[str, Any]) -> None:
    """Published cycles (``last_emitted``) need the cycle numbering they were numbered by (``ingest.cycle``, at
    or after the last of them): without it the next cycles are numbered from the start again and every one
    is skipped as published before."""
    published = [c for c in state.get("last_emitted", {}).values() if isinstance(c, int)]
    if not published:
        return
    ingest = state.get("ingest")
    cycle = ingest.get("cycle") if isinstance(ingest, dict) else None
    if not isinstance(cycle, int):
        raise StateError(f"it has published cycles up to {max(published)} (last_emitted) but no cycle numbering "
                         "(ingest.cycle): the next cycles would all be skipped as published")
    if cycle < max(published):
        raise StateError(f"ingest.cycle = {cycle} is before the last published cycle {max(published)} "
                         "(last_emitted): the cycles up to it would be skipped as published")


def _drop_unconfigured(state: dict[str, Any], joints: tuple[int, ...] | None) -> None:
    """Forget saved joints the config no longer monitors (a warning names them); the others are kept."""
    if joints is None:
        return
    dropped: set[str] = set()
    for section in ("last_emitted", "joints"):
        table = state.get(section, {})
        for key in list(table):
            joint = _joint_index(key)
            if joint is not None and 0 <= joint < MAX_JOINT and joint not in joints:
                dropped.add(key)
                del table[key]
    if dropped:
        log.warning("saved state of joints %s dropped: not among the configured joints %s",
                    sorted(dropped, key=int), list(joints))


def _joint_index(key: str) -> int | None:
    try:
        return int(key)
    except ValueError:
        return None


def _check_joint(key: str, where: str) -> None:
    """A joint index 0 … MAX_JOINT − 1 (joints outside the config were dropped before)."""
    joint = _joint_index(key)
    if joint is None:
        raise StateError(f"{where}: {key!r} is not a joint index")
    if not 0 <= joint < MAX_JOINT:
        raise StateError(f"{where}: joint {joint} is not one of 0 … {MAX_JOINT - 1}")


def _check_tree(node: Any, path: str, depth: int) -> None:
    """Bounds on every value below ``node`` (``path`` names it in messages)."""
    if depth > MAX_DEPTH:
        raise StateError(f"{path}: nested deeper than {MAX_DEPTH} levels")
    if isinstance(node, dict):
        if len(node) > MAX_LIST:
            raise StateError(f"{path}: {len(node)} keys, more than {MAX_LIST}")
        for key, value in node.items():
            _check_tree(value, f"{path}.{key}", depth + 1)
    elif isinstance(node, list):
        if len(node) > MAX_LIST:
            raise StateError(f"{path}: {len(node)} elements, more than {MAX_LIST}")
        if all(type(v) in (int, float) for v in node):     # the common case: a numeric array
            _check_numbers(node, path)
        else:
            for i, value in enumerate(node):
                _check_tree(value, f"{path}[{i}]", depth + 1)
    elif isinstance(node, float | int) and not isinstance(node, bool):
        _check_numbers([node], path)
    elif isinstance(node, str) and len(node) > MAX_STRING:
        raise StateError(f"{path}: a string of {len(node)} characters")


def _check_numbers(values: list[int | float], path: str) -> None:
    for v in values:       # an int is compared exactly: float() of a 400-digit int overflows
        if not (abs(v) <= MAX_MAGNITUDE if isinstance(v, int) else math.isfinite(v) and abs(v) <= MAX_MAGNITUDE):
            raise StateError(f"{path}: {v!r} is not a finite number within ±{MAX_MAGNITUDE:g}")
