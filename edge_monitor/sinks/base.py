"""The sink interface: where records go (JSON Lines, Zenoh, Rerun, a summary table, …).

A sink takes typed records (:mod:`edge_monitor.records`) and must never raise into the agent: it
counts its own failures. Sinks are built by name through :data:`edge_monitor.app.SINK_BUILDERS`.
"""

from __future__ import annotations

from typing import Protocol

from edge_monitor.records import Alarm, Health, Symptom


class Sink(Protocol):
    """Receives every record the agent publishes."""

    def on_symptom(self, symptom: Symptom) -> None: ...
    def on_alarm(self, alarm: Alarm) -> None: ...
    # optional: def on_advisory(self, advisory: Advisory) -> None (the agent calls it where a sink has it)
    def on_health(self, health: Health) -> None: ...
    def close(self) -> None: ...


class LastSymptomSink:
    """Keeps the last symptom record (JSON form) per joint, and the last "raised" alarm record per joint
    (with the prognosis then), e.g. for a summary table."""

    def __init__(self) -> None:
        self.last: dict[int, dict] = {}
        self.raised: dict[int, dict] = {}

    def on_symptom(self, symptom: Symptom) -> None:
        self.last[symptom.joint] = symptom.to_dict()

    def on_alarm(self, alarm: Alarm) -> None:
        """The crossings are read from the run statistics; a raised fault is kept for its prognosis."""
        if alarm.state == "raised":
            self.raised[alarm.joint] = alarm.to_dict()

    def on_health(self, health: Health) -> None:
        """Not needed for a summary."""

    def close(self) -> None:
        """Nothing to release."""
