"""Plant changes over a run: a timeline of events, each at a test cycle (docs/SIMULATOR.md, "Timeline").

An event at cycle N changes any of the plant conditions from cycle N on — the load range |τl|
(fraction of max torque), the ambient temperature [°C], the controller's payload mass error
(fraction) and σl of its load estimate — and/or stops the robot for ``stop_hours`` [h] before
cycle N. A change stays in effect until a later event changes it again. Events are listed in
strictly increasing cycle order (one event per cycle; combine the changes of one cycle in it).

:func:`conditions_at` gives the conditions in effect at a cycle, :func:`stop_before` the stop that
precedes it. A stop and the event's changes start together: during a stop the robot cools towards
the event's ambient, and its new load range etc. apply from cycle N.
"""

from __future__ import annotations

from dataclasses import dataclass, fields, replace
from typing import Any, Iterable, Mapping, Sequence

from protocol.numbers import is_finite_number

#: The plant conditions an event can change (the SimConfig fields of the same names).
CONDITIONS = ("load_range", "ambient", "payload_error", "load_std")
#: Keys of an event: its cycle, the conditions, and the stop.
EVENT_KEYS = ("cycle", *CONDITIONS, "stop_hours")
#: Longest stop [h] (a year): longer is surely a typing error.
MAX_STOP_HOURS = 8760.0


class TimelineError(ValueError):
    """Invalid timeline event; the message names the field."""


def check_condition(name: str, value: Any, where: str) -> None:
    """Raise :class:`TimelineError` naming ``where.name`` unless ``value`` is valid for the condition
    ``name`` (the ranges of the SimConfig fields of the same names)."""
    field_name = f"{where}.{name}" if where else name
    if name == "load_range":
        ok = (isinstance(value, (tuple, list)) and len(value) == 2 and all(is_finite_number(v) for v in value)
              and 0.0 <= value[0] <= value[1] <= 1.0)
        if not ok:
            raise TimelineError(f"{field_name}: need 0 ≤ LOW ≤ HIGH ≤ 1 (|τl|, fraction of max torque), "
                                f"got {value!r}")
    elif name == "ambient":
        if not (is_finite_number(value) and -40.0 <= value <= 150.0):
            raise TimelineError(f"{field_name}: must be −40 … 150 °C, got {value!r}")
    elif name == "payload_error":
        if not (is_finite_number(value) and -0.5 <= value <= 0.5):
            raise TimelineError(f"{field_name}: must be −0.5 … 0.5 (a fraction of the payload mass), got {value!r}")
    elif name == "load_std":
        if not (is_finite_number(value) and 0.0 <= value <= 0.5):
            raise TimelineError(f"{field_name}: must be 0 … 0.5, got {value!r}")
    else:
        raise TimelineError(f"{field_name}: not a plant condition; use one of {', '.join(CONDITIONS)}")


@dataclass(frozen=True)
class PlantConditions:
    """The conditions in effect at one cycle: |τl| range, ambient [°C], payload error, σl."""

    load_range: tuple[float, float]
    ambient: float
    payload_error: float
    load_std: float

    def to_dict(self) -> dict[str, Any]:
        return {"load_range": list(self.load_range), "ambient": self.ambient,
                "payload_error": self.payload_error, "load_std": self.load_std}


@dataclass(frozen=True)
class PlantEvent:
    """At test cycle ``cycle`` (0-based): the conditions given (``None`` = unchanged) apply from that
    cycle on, and with ``stop_hours`` the robot stands still that many hours before it."""

    cycle: int
    load_range: tuple[float, float] | None = None
    ambient: float | None = None
    payload_error: float | None = None
    load_std: float | None = None
    stop_hours: float | None = None

    def __post_init__(self) -> None:
        check_event({f.name: getattr(self, f.name) for f in fields(self)}, "timeline event")

    def changes(self) -> dict[str, Any]:
        """The conditions this event sets, by name."""
        return {name: getattr(self, name) for name in CONDITIONS if getattr(self, name) is not None}

    def to_dict(self) -> dict[str, Any]:
        out: dict[str, Any] = {"cycle": self.cycle}
        for f in fields(self)[1:]:
            value = getattr(self, f.name)
            if value is not None:
                out[f.name] = list(value) if isinstance(value, tuple) else value
        return out


def check_event(values: Mapping[str, Any], where: str) -> None:
    """Raise :class:`TimelineError` naming ``where.FIELD`` for the first invalid field of an event's
    ``values`` (field name → value; ``None`` or absent = not set)."""
    cycle = values.get("cycle")
    if isinstance(cycle, bool) or not isinstance(cycle, int) or cycle < 0:
        raise TimelineError(f"{where}.cycle: expected a test-cycle number ≥ 0, got {cycle!r}")
    changes = {name: values[name] for name in CONDITIONS if values.get(name) is not None}
    for name, value in changes.items():
        check_condition(name, value, where)
    stop = values.get("stop_hours")
    if stop is not None and not (is_finite_number(stop) and 0 < stop <= MAX_STOP_HOURS):
        raise TimelineError(f"{where}.stop_hours: must be > 0 and ≤ {MAX_STOP_HOURS:g} h, got {stop!r}")
    if not changes and stop is None:
        raise TimelineError(f"{where}: changes nothing; give one or more of {', '.join(EVENT_KEYS[1:])}")


def check_order(events: Sequence[PlantEvent], where: str) -> None:
    """Raise :class:`TimelineError` unless the cycles strictly increase (``where[i].cycle`` named)."""
    for i in range(1, len(events)):
        if events[i].cycle <= events[i - 1].cycle:
            raise TimelineError(f"{where}[{i}].cycle: {events[i].cycle} must be greater than the previous event's "
                                f"cycle {events[i - 1].cycle} (list events in cycle order, one per cycle)")


def conditions_at(base: PlantConditions, timeline: Iterable[PlantEvent], cycle: int) -> PlantConditions:
    """The conditions in effect at ``cycle``: ``base`` with the changes of every event at or before it."""
    current = base
    for event in timeline:
        if event.cycle > cycle:
            break
        current = replace(current, **event.changes())
    return current


def stop_before(timeline: Iterable[PlantEvent], cycle: int) -> float:
    """Hours the robot stands still right before ``cycle`` (0.0: it runs straight on)."""
    for event in timeline:
        if event.cycle == cycle:
            return float(event.stop_hours or 0.0)
    return 0.0


def merge_timelines(base: Sequence[PlantEvent], extra: Sequence[PlantEvent]) -> tuple[PlantEvent, ...]:
    """``base`` with the events of ``extra`` added in cycle order; at a cycle both name, the fields
    ``extra`` sets win (a command-line ``--event`` over a scenario file's timeline)."""
    merged: dict[int, PlantEvent] = {e.cycle: e for e in base}
    for event in extra:
        old = merged.get(event.cycle)
        updates = {f.name: getattr(event, f.name) for f in fields(event) if getattr(event, f.name) is not None}
        merged[event.cycle] = replace(old, **updates) if old is not None else event
    return tuple(merged[c] for c in sorted(merged))


def plant_event_from_mapping(doc: Mapping[str, Any], where: str) -> PlantEvent:
    """A scenario table ``{cycle = 620, load_range = [0.6, 1.0], stop_hours = 56, …}`` → :class:`PlantEvent`;
    a bad or unknown key raises :class:`TimelineError` naming ``where.KEY``."""
    unknown = sorted(set(doc) - set(EVENT_KEYS))
    if unknown:
        raise TimelineError(f"{where}: unknown field(s) {unknown}; known: {', '.join(EVENT_KEYS)}")
    if "cycle" not in doc:
        raise TimelineError(f"{where}.cycle: required (the test cycle the event happens at)")
    values: dict[str, Any] = {"cycle": doc["cycle"]}
    for name in EVENT_KEYS[1:]:
        if name not in doc:
            continue
        value = doc[name]
        if name == "load_range":
            check_condition(name, value, where)
            values[name] = (float(value[0]), float(value[1]))
        elif is_finite_number(value):
            values[name] = float(value)
        else:
            raise TimelineError(f"{where}.{name}: expected a finite number, got {value!r}")
    check_event(values, where)
    return PlantEvent(**values)


def parse_event(text: str) -> PlantEvent:
    """The command-line form ``CYCLE:KEY=VALUE[,KEY=VALUE…]`` (ranges as ``LOW:HIGH``), e.g.
    ``620:load_range=0.6:1.0`` or ``900:stop_hours=56,ambient=25``; errors name ``event.KEY`` and
    quote ``text``."""
    try:
        return plant_event_from_mapping(_event_fields(text), "event")
    except TimelineError as exc:
        raise TimelineError(f"{exc} (in --event {text!r})") from None


def _event_fields(text: str) -> dict[str, Any]:
    cycle_text, sep, rest = text.partition(":")
    if not sep or not rest.strip():
        raise TimelineError(f"event: expected CYCLE:KEY=VALUE[,KEY=VALUE…] with KEY one of "
                            f"{', '.join(EVENT_KEYS[1:])}")
    try:
        doc: dict[str, Any] = {"cycle": int(cycle_text)}
    except ValueError:
        raise TimelineError(f"event.cycle: expected an integer test-cycle number, got {cycle_text!r}") from None
    for item in rest.split(","):
        key, eq, raw = (s.strip() for s in item.partition("="))
        if not eq:
            raise TimelineError(f"event: expected KEY=VALUE, got {item!r}")
        if key not in EVENT_KEYS[1:]:
            raise TimelineError(f"event: unknown key {key!r}; use {', '.join(EVENT_KEYS[1:])}")
        if key in doc:
            raise TimelineError(f"event.{key}: given twice")
        try:
            doc[key] = [float(v) for v in raw.split(":")] if key == "load_range" else float(raw)
        except ValueError:
            raise TimelineError(f"event.{key}: expected {'LOW:HIGH' if key == 'load_range' else 'a number'}, "
                                f"got {raw!r}") from None
    return doc
