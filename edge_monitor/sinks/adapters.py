"""Adapters from the agent's sink interface to Zenoh publication and the Rerun view.

Both adapters swallow and count failures (the publisher and the Rerun sink count them too), so an
unreachable router or an unwritable recording never stops monitoring.
"""

from __future__ import annotations

import logging
from typing import Any

import numpy as np

from edge_monitor.pipeline.joint_monitor import CycleOutput

log = logging.getLogger(__name__)


def _density_lists(density: dict | None) -> dict | None:
    if not density:
        return None
    return {k: (np.asarray(v, dtype=float).tolist() if v is not None else None) for k, v in density.items()}


class ZenohSink:
    """Publishes symptoms, friction curves, alarms and health through a ``SymptomPublisher``."""

    def __init__(self, publisher: Any) -> None:
        self.publisher = publisher

    def on_symptom(self, output: CycleOutput) -> None:
        rec = output.symptom
        self.publisher.publish_symptom(rec)
        self.publisher.publish_friction(rec["joint"], rec["cycle"], rec["friction"])

    def on_alarm(self, alarm: dict[str, Any]) -> None:
        self.publisher.publish_alarm(alarm)

    def on_health(self, health: dict[str, Any]) -> None:
        self.publisher.publish_health(health)

    def close(self) -> None:
        self.publisher.close()


class RerunViewSink:
    """Draws each symptom (with the cycle's torque density over the nominal one) in Rerun."""

    def __init__(self, rerun_sink: Any) -> None:
        self.rerun = rerun_sink

    def on_symptom(self, output: CycleOutput) -> None:
        record = output.symptom
        density = _density_lists(output.extras.get("density"))
        if density is not None:
            record = {**record, "density": density}
        self.rerun.log_symptom(record)

    def on_alarm(self, alarm: dict[str, Any]) -> None:
        self.rerun.log_alarm(alarm)

    def on_health(self, health: dict[str, Any]) -> None:
        flat = {k: v for k, v in health.items() if isinstance(v, (int, float)) and not isinstance(v, bool)}
        self.rerun.log_health(flat, robot=health.get("robot"))

    def close(self) -> None:
        self.rerun.close()
