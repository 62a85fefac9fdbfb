"""The agent pipeline: frames → E2E checks → per-joint samples → cycles → symptoms → sinks.

``Agent.update`` takes a block of raw frames as numpy arrays and is shared by the live loop
(``edge-monitor run``) and the deterministic replay (``edge-monitor replay``). Cycle boundaries come
from the controller's status frame; without it, each joint infers them from the repetition of its
plateau sequence (see :mod:`edge_monitor.pipeline.cycle_assembly`).
"""

from __future__ import annotations

import dataclasses
import logging
import threading
import time
from dataclasses import replace
from typing import Any, Callable, Iterable, Sequence

from numpy.typing import NDArray

from edge_monitor.errors import StateError, UnknownJointError
from edge_monitor.pipeline.agent_config import AgentConfig
from edge_monitor.pipeline.cycle_rate import BudgetRate
from edge_monitor.pipeline.detectors import Acknowledgement
from edge_monitor.pipeline.fault_grouping import new_crossings
from edge_monitor.pipeline.joint_monitor import JointMonitor
from edge_monitor.pipeline.run_stats import RunStats
from edge_monitor.pipeline.state_store import StateSaveError, StateStore
from edge_monitor.pipeline.state_validation import validate_state
from edge_monitor.records import Alarm, Health, Symptom, utc_now, utc_text
from edge_monitor.sinks.base import Sink
from edge_monitor.sources.ingest import Ingest
from edge_monitor.sources.samples import IngestBlock, SampleSource
from edge_monitor.stats.sequential_detector import Calibrator

log = logging.getLogger(__name__)


class Agent:
    """Holds one :class:`JointMonitor` per joint and routes ingested samples to them."""

    def __init__(self, config: AgentConfig, sinks: Iterable[Sink] = (), state_store: StateStore | None = None,
                 calibrator: Calibrator | None = None, source: SampleSource | None = None):
        self.config = config
        self.calibrator = calibrator     # None: detectors calibrate inline (replay, studies)
        self.sinks = list(sinks)
        self.store = state_store
        # the sample source (edge_monitor.sources): our frames, or a mapping's (foreign_source.open_source)
        self.ingest: SampleSource = source if source is not None else Ingest.for_config(config)
        self.joints: dict[int, JointMonitor] = {}
        self.budget = BudgetRate(config.decision)       # the cycle rate the false-alarm budget is for
        self.stats = RunStats()
        self._open_cycle: int | None = None
        self._last_emitted: dict[int, int] = {}
        self._partial_cycle: int | None = None   # its start (first after a start) or end (a restart) unseen
        self._restored_joint_states: dict[int, dict] = {}
        self._open_last_segment = -1              # highest segment seen in the open cycle
        self._complete_last_segment: int | None = None    # … in the last cycle that ended normally
        self._last_frame_time: float | None = None   # timestamp of the last frame routed (bus or log) [s]
        self.lock = threading.RLock()     # processing vs. state queries from output threads
        if state_store is not None:
            self._restore(state_store.load())
            self.stats.states_rejected = state_store.rejected

    # ------------------------------------------------------------------ input
    def update(self, ids: NDArray, data: NDArray, dlc: NDArray, timestamps: NDArray) -> list[Symptom]:
        """Process one block of frames (``ids`` (n,), ``data`` (n, 8) uint8, ``dlc`` (n,), ``timestamps`` s)."""
        with self.lock:
            block = self.ingest.update(ids, data, dlc, timestamps)
            return self._route(block)

    def flush_source(self) -> list[Symptom]:
        """End of stream: the samples a source still holds (a foreign source waits for plateaus to end)."""
        flush = getattr(self.ingest, "flush", None)
        return self.update_ingested(flush()) if flush is not None else []

    def update_ingested(self, block: IngestBlock) -> list[Symptom]:
        """Process samples that are already decoded, checked and labelled (the simulator's cycle-level
        mode, :mod:`edge_monitor.offline.fast_path`): everything after ingest runs as for frames."""
        with self.lock:
            return self._route(block)

    @property
    def frames_total(self) -> int:
        """Frames taken in so far (all of them, including rejected ones)."""
        return self.ingest.c.frames_total

    def joint_state(self, joint: int) -> dict[str, Any]:
        """Snapshot of one joint's models and detector state (for the read-only state queryable): also of
        a joint restored from the saved state but not seen yet (``"restored": true``); ``"known": false``
        for a joint with nothing seen or learned (e.g. configured, not on the bus yet)."""
        with self.lock:
            monitor = self.joints.get(joint)
            last = self._last_emitted.get(joint)
            if monitor is not None:
                return {"joint": joint, "known": True, "last_cycle": last, **monitor.state_dict()}
            saved = self._restored_joint_states.get(joint)
            if saved is not None:
                return {"joint": joint, "known": True, "restored": True, "last_cycle": last, **saved}
            return {"joint": joint, "known": False, "last_cycle": last}

    def known_joints(self) -> list[int]:
        """Joints the agent knows: seen on the bus, restored from the saved state, or configured."""
        with self.lock:
            return sorted(set(self.joints) | set(self._restored_joint_states) | set(self.config.joints or ()))

    def _route(self, block: IngestBlock) -> list[Symptom]:
        outputs: list[Symptom] = []
        for run in block.runs:
            if run.cycle is not None and run.cycle != self._open_cycle:
                first = self._open_cycle is None
                if self._open_cycle is not None:
                    closing, self._open_cycle = self._open_cycle, None    # a close that raises is not retried
                    if run.previous_cut:       # a controller restart cut it: published, kept from the detectors
                        self._partial_cycle = closing
                    else:
                        self._complete_last_segment = self._open_last_segment
                    outputs += self._close_cycle(closing)
                self._open_last_segment = -1
                if run.starts_at_boundary is False or (first and run.starts_at_boundary is not True):
                    self._partial_cycle = run.cycle     # its start was not seen by this instance
                self._open_cycle = run.cycle
            if run.cycle is not None:
                self._open_last_segment = max([self._open_last_segment] + [
                    int(x.segment.max()) for x in run.samples.values() if x.segment.size])
            for joint, samples in run.samples.items():
                monitor = self._monitor(joint)
                inferred = monitor.update(samples.tick, samples.speed, samples.torque,
                                          samples.segment if run.cycle is not None else None)
                for symptom in inferred:     # no status frame: cycle inferred by the joint itself
                    outputs += self._emit(symptom)
            for joint, status in run.joint_status.items():
                self._monitor(joint).add_status(status.load_estimate, status.load_std, status.motor_temperature)
            if run.last_time is not None:
                self._last_frame_time = run.last_time
        return outputs

    def _monitor(self, joint: int) -> JointMonitor:
        monitor = self.joints.get(joint)
        if monitor is None:
            monitor = self._restored_monitor(joint) or JointMonitor(joint, self.config, self.calibrator)
            monitor.rate = self.budget                  # the prognosis counts days at the measured rate
            self.joints[joint] = monitor
            log.info("joint %d: monitoring started", joint)
            if not self._count_joints():
                monitor.retarget(self.budget.arl0)      # no-op unless the measured rate moved the target
        return monitor

    def _count_joints(self) -> bool:
        """Split the budget over the joints seen or restored where none are stated; whether every joint's
        thresholds were retargeted for it."""
        arl0 = self.budget.count_joints(len(set(self.joints) | set(self._restored_joint_states)))
        if arl0 is None:
            return False
        started = self._retarget_all(arl0)
        (log.warning if started else log.debug)(
            "false-alarm budget split over the %d joint(s) seen: %.3g cycles per detector%s (state [decision] "
            "joints_per_robot to fix the split)", self.budget.joints, arl0,
            f"; re-deriving {started} learned threshold(s)" if started else "")
        return True

    def _retarget_all(self, arl0: float | None) -> int:
        """Every joint's thresholds re-derived for ``arl0`` [cycles per detector] (None: none); how many."""
        return 0 if arl0 is None else sum(monitor.retarget(arl0) for monitor in self.joints.values())

    def _restored_monitor(self, joint: int) -> JointMonitor | None:
        """The joint's monitor from the saved state, or None (nothing saved, or saved models that do
        not load: the joint relearns, with a warning and ``joint_states_rejected`` counted)."""
        saved = self._restored_joint_states.pop(joint, None)
        if saved is None:
            return None
        try:
            return JointMonitor.from_state(joint, self.config, saved, self.calibrator)
        except Exception as exc:        # noqa: BLE001 — the state is untrusted input: any failure → relearn
            log.warning("joint %d: saved models unusable (%s: %s); relearning this joint", joint,
                        type(exc).__name__, exc)
            self.stats.joint_states_rejected += 1
            return None

    def _close_cycle(self, cycle: int) -> list[Symptom]:
        outputs: list[Symptom] = []
        self.stats.cycles += 1
        partial = cycle == self._partial_cycle
        for joint in sorted(self.joints):
            monitor = self.joints[joint]
            if cycle <= self._last_emitted.get(joint, -1):
                # published before a restart (e.g. a log replayed again): its data must not enter the
                # detectors a second time
                monitor.discard_cycle()
                self.stats.duplicate_cycles_skipped += 1
                continue
            symptom = monitor.end_cycle(cycle, partial=partial)
            if partial:
                self.stats.partial_cycles += 1
            outputs += self._emit(symptom)
        self._retarget_all(self.budget.update(self._last_frame_time))   # None: the rate did not move
        return outputs

    def _emit(self, symptom: Symptom) -> list[Symptom]:
        # the cycle ended with the last frame routed before the one that closes it (bus or log time)
        symptom.utc = utc_text(self._last_frame_time)
        symptom.alarms = [dataclasses.replace(alarm, utc=symptom.utc) for alarm in symptom.alarms]
        symptom.advisories = [dataclasses.replace(a, utc=symptom.utc) for a in symptom.advisories]
        self._last_emitted[symptom.joint] = symptom.cycle
        self.stats.symptoms += 1
        for alarm in symptom.alarms:
            crossed = new_crossings(alarm)
            self.stats.alarms += crossed
            self.stats.faults += alarm.state == "raised"
            self.stats.chattering += alarm.state == "chattering"
            log.warning("ALARM robot %s joint %d cycle %d: fault %s %s by %s (%d detector(s) agree)", alarm.robot,
                        alarm.joint, alarm.cycle, alarm.fault, alarm.state, ", ".join(c["quantity"] for c in crossed),
                        len(alarm.detectors or ()))
        for advisory in symptom.advisories:
            self.stats.advisories += 1
            log.warning("advisory robot %s joint %d cycle %d: %s", advisory.robot, advisory.joint, advisory.cycle,
                        advisory.to_dict()["message"])
        for sink in self.sinks:
            self._deliver(sink.on_symptom, symptom)
            for alarm in symptom.alarms:
                self._deliver(sink.on_alarm, alarm)
            on_advisory = getattr(sink, "on_advisory", None)
            if on_advisory is not None:
                for advisory in symptom.advisories:
                    self._deliver(on_advisory, advisory)
        return [symptom]

    def sink_errors(self) -> int:
        """Records a sink failed to take: exceptions caught here plus the sinks' own count of records
        they could not write (``failures``, e.g. the JSONL file on a full disk)."""
        return self.stats.sink_errors + sum(int(getattr(sink, "failures", 0)) for sink in self.sinks)

    def _deliver(self, fn: Callable[[Any], None], record: Any) -> None:
        try:
            fn(record)
        except Exception:  # a sink must never stop the agent
            self.stats.sink_errors += 1
            log.exception("output sink failed; counted and continuing")

    # ------------------------------------------------------------------ control
    def finish(self, close_open_cycle: bool = True) -> list[Symptom]:
        """End of stream: optionally close the open cycle (replay of a complete log)."""
        with self.lock:
            return self._finish(close_open_cycle)

    def _finish(self, close_open_cycle: bool) -> list[Symptom]:
        outputs: list[Symptom] = []
        if not close_open_cycle:
            for monitor in self.joints.values():
                monitor.catch_up()             # the gathered samples count, even in a cycle left open
            return outputs
        for monitor in self.joints.values():
            monitor.flush()
        if self._open_cycle is not None:
            if self._complete_last_segment is not None and self._open_last_segment < self._complete_last_segment:
                log.info("cycle %d ends at segment %d of %d (the stream stopped inside it): published partial",
                         self._open_cycle, self._open_last_segment, self._complete_last_segment)
                self._partial_cycle = self._open_cycle
            outputs = self._close_cycle(self._open_cycle)
            self._open_cycle = None
        else:   # no status frames: each joint closes its own inferred cycle if it holds data
            for _, monitor in sorted(self.joints.items()):
                if monitor.has_cycle_data():
                    outputs += self._emit(monitor.end_cycle(monitor.cycles))
        return outputs

    def _known_monitor(self, joint: int, what: str) -> JointMonitor:
        """The monitor of a joint the agent monitors (seen on the bus or restored from the state) for
        ``what`` an operator asks; :class:`UnknownJointError` (a ``ValueError``) naming the fix otherwise."""
        joint = int(joint)
        if self.config.joints is not None and joint not in self.config.joints:
            raise UnknownJointError(f"joint {joint}: not monitored "
                                    f"(configured joints: {list(self.config.joints)})")
        if joint not in self.joints and joint not in self._restored_joint_states:
            raise UnknownJointError(f"joint {joint}: nothing learned yet (not seen on the bus, no saved state); "
                                    f"{what} is only needed for a joint with learned models")
        return self._monitor(joint)

    def declare_maintenance(self, joint: int) -> list[Alarm]:
        """Gearbox replaced or serviced: relearn the joint's nominal models; the open fault is cleared
        (one "cleared" alarm record naming its latched detectors, returned and sent to the sinks). Thread-safe.
        Only for a joint the agent monitors (seen on the bus or restored from the state)."""
        with self.lock:
            monitor = self._known_monitor(joint, "a maintenance declaration")
            joint = monitor.joint
            cycle = self._last_emitted.get(joint, -1)
            cleared = [dataclasses.replace(alarm, utc=utc_now())
                       for alarm in monitor.declare_maintenance(cycle, self.config)]
            log.warning("joint %d: maintenance declared after cycle %d; nominal models are relearned", joint, cycle)
            for alarm in cleared:
                for sink in self.sinks:
                    self._deliver(sink.on_alarm, alarm)
            self.save_state()
            return cleared

    def acknowledge(self, joint: int, quantities: Sequence[str] | None = None, by: str | None = None,
                    note: str | None = None) -> Acknowledgement:
        """An operator judged the latched alarms of ``joint`` (``quantities``, default all) false: each
        restarts its statistic on the same nominal and threshold; one "acknowledged" alarm record of
        their fault naming them (``by``/``note`` in it), returned and sent to the sinks; the state is saved at once
        (a restart does not bring the alarm back). Quantities without a latched alarm are a no-op, named
        in the result. Thread-safe. ``ValueError`` for a joint or quantity not monitored."""
        with self.lock:
            monitor = self._known_monitor(joint, "an acknowledgement")
            cycle = self._last_emitted.get(monitor.joint, -1)
            result = monitor.acknowledge(cycle, quantities)
            result = replace(result, alarms=tuple(replace(a, by=by, note=note, utc=utc_now()) for a in result.alarms))
            for alarm in result.alarms:
                log.warning("joint %d: %s alarm ACKNOWLEDGED (fault %s) after cycle %d by %s: the statistics "
                            "restart on the same nominal and threshold", alarm.joint, ", ".join(
                                d["quantity"] for d in alarm.detectors or ()), alarm.fault, cycle, by or "(unnamed)")
                self.stats.acknowledged += 1
                for sink in self.sinks:
                    self._deliver(sink.on_alarm, alarm)
            if result.not_latched:
                log.info("joint %d: no latched alarm on %s: nothing to acknowledge", monitor.joint,
                         ", ".join(result.not_latched))
            if result.alarms:
                self.save_state()
            return result

    def poll(self, now: float) -> None:
        """Periodic work without frames: E2E timeout supervision (NO_NEW_DATA per identifier)."""
        with self.lock:
            self.ingest.e2e.poll(now)

    def publish_health(self, extra: dict[str, Any] | None = None) -> Health:
        """Build the health record (plus ``extra`` counters of the caller) and send it to every sink."""
        health = self.health(extra)
        for sink in self.sinks:
            self._deliver(sink.on_health, health)
        return health

    def health(self, extra: dict[str, Any] | None = None) -> Health:
        with self.lock:
            wall = time.perf_counter() - self.stats.started
            h: dict[str, Any] = self.ingest.counters()
            h.update({
                "cycles": self.stats.cycles, "symptoms": self.stats.symptoms,
                "alarms": len(self.stats.alarms), "faults": self.stats.faults, "advisories": self.stats.advisories,
                "sink_errors": self.sink_errors(),
                "state_save_errors": 0 if self.store is None else self.store.save_errors,
                "duplicate_cycles_skipped": self.stats.duplicate_cycles_skipped,
                "partial_cycles": self.stats.partial_cycles, "states_rejected": self.stats.states_rejected,
                "joint_states_rejected": self.stats.joint_states_rejected,
                "alarms_acknowledged": self.stats.acknowledged, "alarms_chattering": self.stats.chattering,
                "wall_s": wall, "frames_per_second": h["frames_total"] / wall if wall > 0 else 0.0,
                "segmentation": {str(j): m.counters()["segmentation"] for j, m in self.joints.items()},
                "skipped": {str(j): m.counters()["skipped"] for j, m in self.joints.items()},
                "detector_cycles_held": {str(j): m.counters()["held"] for j, m in self.joints.items()},
                "coverage": {str(j): m.coverage_summary() for j, m in self.joints.items()},
                "e2e": dict(self.ingest.e2e.stats), "no_new_data": self.ingest.e2e.stats["no_new_data"],
                **self.budget.counters(),
            })
            h.update(extra or {})
            return Health(self.config.robot, h)

    def run_statistics(self) -> dict[str, Any]:
        """The run statistics (``replay --json``, docs/OUTPUTS.md)."""
        h = self.health().counters
        keys = ("frames_total", "frames_ok", "crc_errors", "counter_lost", "repeated", "unknown_id", "malformed")
        out = {k: h[k] for k in keys}
        out.update({"cycles": self.stats.cycles, "symptoms": self.stats.symptoms, "faults": self.stats.faults,
                    "alarms": list(self.stats.alarms), "alarms_chattering": self.stats.chattering,
                    "advisories": self.stats.advisories,
                    "frames_per_second": h["frames_per_second"], "wall_s": h["wall_s"]})
        out["details"] = {k: v for k, v in h.items() if k not in out and k not in ("e2e", "no_new_data")}
        return out

    # ------------------------------------------------------------------ persistence
    def state_dict(self) -> dict[str, Any]:
        with self.lock:
            joints = {str(j): m.state_dict() for j, m in self.joints.items()}
            joints.update({str(j): s for j, s in self._restored_joint_states.items()})
            return {"robot": self.config.robot,
                    "last_emitted": {str(j): c for j, c in self._last_emitted.items()},
                    "ingest": self.ingest.state_dict(), "joints": joints, "cycle_rate": self.budget.state_dict()}

    def save_state(self) -> bool:
        """Persist the state; False (logged, counted in ``state_save_errors``, the previous file kept)
        when it cannot be written, e.g. on a full disk: monitoring goes on."""
        if self.store is None:
            return True
        with self.lock:            # one snapshot at a time, in order
            for sink in self.sinks:          # what the state counts as published is on disk first
                sync = getattr(sink, "sync", None)
                if sync is not None:
                    self._deliver(lambda s: s.sync(), sink)
            try:
                self.store.save(self.state_dict())
            except StateSaveError as exc:
                if self.store.save_errors in (1, 10, 100) or self.store.save_errors % 1000 == 0:
                    log.error("%s (failure #%d, logged at 1, 10, 100, every 1000; monitoring goes on)",
                              exc, self.store.save_errors)
                return False
        return True

    def _restore(self, state: dict[str, Any] | None) -> None:
        if not state:
            return
        try:
            validate_state(state, self.config.robot, self.config.joints)
        except StateError as exc:
            if self.store is not None:
                self.store.reject(str(exc))
            return
        if state.get("ingest"):
            self.ingest.load_state(state["ingest"])
        self._last_emitted = {int(j): c for j, c in state.get("last_emitted", {}).items()}
        if state.get("cycle_rate"):
            self.budget.load_state(state["cycle_rate"])
        self._restored_joint_states = {int(j): s for j, s in state.get("joints", {}).items()}
        if self._restored_joint_states:
            self._count_joints()
        log.info("restored state of joints %s (last cycles %s)", sorted(self._restored_joint_states),
                 self._last_emitted)

    def close(self) -> None:
        self.save_state()
        for sink in self.sinks:
            self._deliver(lambda s: s.close(), sink)
