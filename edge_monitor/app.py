"""Wiring: one builder for the agent with its sinks, shared by ``run``, ``replay`` and ``demo``.

The command modules only parse arguments into an :class:`AgentConfig` and :class:`Outputs`;
:func:`build_app` opens what the outputs name (JSONL file, Zenoh session and publisher, Rerun
recording, the maintenance and acknowledgement subscribers) with the agent, and registers their closing on an ExitStack.
"""

from __future__ import annotations

import logging
from contextlib import ExitStack
from dataclasses import dataclass, field
from typing import Any, Callable

from edge_monitor.pipeline.agent import Agent
from edge_monitor.pipeline.agent_config import AgentConfig
from edge_monitor.pipeline.state_store import StateStore
from edge_monitor.sinks.base import Sink

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class Outputs:
    """Where the agent's records go besides its return values.

    ``zenoh``: a :class:`~edge_monitor.sinks.zenoh_session.ZenohOptions`, or None for no Zenoh;
    ``rerun``: ``off`` | ``save:PATH`` | ``spawn`` | ``connect:URL``; ``maintenance``: listen for
    operator requests put on Zenoh, maintenance declarations and acknowledgements (accepted only as
    ``config.maintenance`` / ``config.acknowledge`` allow).
    """

    jsonl: str | None = None
    zenoh: Any = None
    rerun: str = "off"
    rerun_fallback: str | None = None
    recording_id: str | None = None
    maintenance: bool = False


@dataclass
class App:
    """An agent with its sinks; ``session`` is the Zenoh session (None without Zenoh)."""

    agent: Agent
    sinks: list[Sink] = field(default_factory=list)
    session: Any = None
    publisher: Any = None
    maintenance_gate: Any = None
    acknowledge_gate: Any = None

    def extra_counters(self) -> dict[str, Any]:
        """Counters of the outputs for the health record (operator request gates, Zenoh delivery)."""
        out: dict[str, Any] = {}
        for gate in (self.maintenance_gate, self.acknowledge_gate):
            if gate is not None:
                out.update(gate.stats())
        if self.publisher is not None:
            out.update(self.publisher.stats())
        return out

    def symptoms_published(self) -> int:
        """Symptoms handed to Zenoh so far (0 without Zenoh)."""
        return 0 if self.publisher is None else int(self.publisher.published.get("symptom", 0))


def _jsonl(config: AgentConfig, outputs: Outputs, app: App, stack: ExitStack) -> Sink | None:
    if not outputs.jsonl:
        return None
    from edge_monitor.sinks.jsonl import JsonlSink
    # alarm raised/cleared events too ("kind": "alarm"); strict: a failed write is counted (sink_errors)
    return JsonlSink(outputs.jsonl, include_alarms=True, rotation=config.jsonl_rotation(), strict=True)


def _zenoh(config: AgentConfig, outputs: Outputs, app: App, stack: ExitStack) -> Sink | None:
    if outputs.zenoh is None:
        return None
    from edge_monitor.sinks.zenoh_publisher import SymptomPublisher, ZenohSink
    from edge_monitor.sinks.zenoh_session import open_session
    app.session = open_session(outputs.zenoh)
    stack.callback(app.session.close)
    app.publisher = SymptomPublisher(app.session, config.robot, config.joints or (),
                                     state_provider=app.agent.joint_state, joints_provider=app.agent.known_joints)
    log.info("zenoh: %s", outputs.zenoh.describe())
    if outputs.maintenance:
        from edge_monitor.sinks.acknowledge import AcknowledgeRequest, parse_request
        from edge_monitor.sinks.control_gate import open_gate

        def acknowledge(joint: int, request: AcknowledgeRequest) -> None:
            app.agent.acknowledge(joint, request.quantities, by=request.by, note=request.note)

        app.maintenance_gate, subscriber = open_gate(app.session, config.robot, config.maintenance,
                                                     app.agent.declare_maintenance)
        stack.callback(subscriber.undeclare)
        app.acknowledge_gate, subscriber = open_gate(app.session, config.robot, config.acknowledge, acknowledge,
                                                     parse_request)
        stack.callback(subscriber.undeclare)
    return ZenohSink(app.publisher)


def _rerun(config: AgentConfig, outputs: Outputs, app: App, stack: ExitStack) -> Sink | None:
    if not outputs.rerun or outputs.rerun == "off":
        return None
    from edge_monitor.sinks.rerun_view import RerunSink, RerunViewSink
    return RerunViewSink(RerunSink.open(outputs.rerun, recording_id=outputs.recording_id,
                                        fallback_save=outputs.rerun_fallback))


#: Sink builders by name, in the order sinks receive records.
SINK_BUILDERS: dict[str, Callable[[AgentConfig, Outputs, App, ExitStack], Sink | None]] = {
    "jsonl": _jsonl, "zenoh": _zenoh, "rerun": _rerun}


def build_app(config: AgentConfig, outputs: Outputs, stack: ExitStack, store: StateStore | None = None,
              live: bool = False, source: Any = None) -> App:
    """The agent and every sink ``outputs`` asks for. Opening failures raise
    :class:`~edge_monitor.sinks.zenoh_session.ZenohSetupError` or
    :class:`~edge_monitor.sinks.rerun_view.RerunSetupError` (both ``ValueError``) with the fix, or
    :class:`~edge_monitor.sinks.jsonl.JsonlOpenError` (an ``OSError``: the JSONL file cannot be used).
    ``live``: detectors calibrate their thresholds in a worker process, so frames keep flowing
    (replay calibrates inline: deterministic). ``source``: a foreign sample source (sources.foreign_source.open_source);
    None: our frames."""
    calibrator = None
    if live and config.decision.enabled and config.decision.pf is None:
        from edge_monitor.stats.calibrators import ProcessCalibrator
        calibrator = ProcessCalibrator()
        stack.callback(calibrator.close)
    app = App(Agent(config, state_store=store, calibrator=calibrator, source=source))
    for name, build in SINK_BUILDERS.items():
        sink = build(config, outputs, app, stack)
        if sink is not None:
            app.sinks.append(sink)
            app.agent.sinks.append(sink)
            log.debug("sink %s open", name)
    _republish_recent(config, app)
    stack.callback(app.agent.close)     # first on exit: saves the state and closes the sinks
    return app


def _republish_recent(config: AgentConfig, app: App) -> None:
    """Send again over Zenoh the symptoms the JSONL file ends with (docs/RELIABILITY.md): after a kill,
    puts Zenoh had not sent yet are lost, while the file (fsynced first) has them."""
    if app.publisher is None:
        return
    from edge_monitor.sinks.jsonl import JsonlSink
    for sink in app.sinks:
        if isinstance(sink, JsonlSink) and sink.recent:
            records = [r for r in sink.recent if r.get("robot") == config.robot]
            sent = app.publisher.republish_symptoms(records)
            log.info("zenoh: %d symptom record(s) of the JSONL file's tail published again", sent)
