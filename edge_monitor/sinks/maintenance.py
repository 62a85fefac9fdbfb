"""Maintenance declarations over Zenoh: a put on ``edge/<robot>/<joint>/maintenance`` asks the agent to
relearn that joint's nominal models (gearbox replaced or serviced) and to clear its alarms.

Gated like every operator request (:mod:`edge_monitor.sinks.control_gate`): off by default, exact keys
only, a joint the robot cannot have (≥ ``MAX_JOINTS``) or the agent does not monitor refused
(``unknown_joint``), at most one accepted per joint per ten minutes, every decision logged; the payload
is free text (logged, escaped and truncated).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, ClassVar

from edge_monitor.sinks.control_gate import ControlGate, RemoteConfig
from edge_monitor.sinks.control_gate import describe_source as describe_source  # re-exported
from edge_monitor.sinks.keys import MAINTENANCE


@dataclass(frozen=True)
class MaintenanceConfig(RemoteConfig):
    """Remote maintenance over Zenoh (the ``[maintenance]`` table): ``remote`` off by default
    (``edge-monitor run --maintenance J`` at start always works); at most ``max_per_joint`` accepted per
    joint in any ``window_s`` seconds."""

    action: ClassVar[str] = MAINTENANCE


class MaintenanceGate(ControlGate):
    """The :class:`ControlGate` of ``edge/<robot>/<joint>/maintenance`` (free-text payload)."""

    def __init__(self, robot: str, **kwargs: Any) -> None:
        super().__init__(robot, MAINTENANCE, **kwargs)
