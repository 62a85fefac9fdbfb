"""Maintenance declarations over Zenoh: a put on ``edge/<robot>/<joint>/maintenance`` asks the agent to
relearn that joint's nominal models (gearbox replaced or serviced) and to clear its alarms."""

from __future__ import annotations

import logging
from typing import Any, Callable

from edge_monitor.sinks.keys import MAINTENANCE, joint_key, parse_key

log = logging.getLogger(__name__)


def listen_for_maintenance(session: Any, robot: str, declare: Callable[[int], Any]) -> Any:
    """Subscribe to ``edge/<robot>/*/maintenance``; each valid put calls ``declare(joint)``. Invalid
    keys and refused declarations are logged, never raised into Zenoh's thread. Returns the
    subscriber (undeclare it to stop)."""

    def on_sample(sample: Any) -> None:
        key = str(sample.key_expr)
        parsed = parse_key(key)
        try:
            if parsed is None or parsed.joint is None or parsed.robot != robot or parsed.kind != MAINTENANCE:
                raise ValueError("not a joint maintenance key of this robot")
            declare(parsed.joint)
        except Exception as exc:   # never raise into Zenoh's thread
            log.error("maintenance declaration on %s ignored: %s", key, exc)

    return session.declare_subscriber(joint_key(robot, "*", MAINTENANCE), on_sample)
