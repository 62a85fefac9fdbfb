"""Per-joint monitor: sample blocks → cycle assembly → registered features → detectors → symptom.

Two entry points share the per-cycle pipeline: the streaming path (:meth:`JointMonitor.update` with
sample blocks, :meth:`JointMonitor.end_cycle` on the controller's cycle boundary) and the cycle-level
path (:meth:`JointMonitor.update_cycle` with a ready :class:`CycleInput`, e.g. the simulator's fast
mode). Per-joint memory is bounded: O(speed levels) + O(KDE grid) + O(GLR window · components).

Sample blocks with the controller's segment codes are gathered up to :data:`SAMPLE_BATCH` samples
before the sample-level work runs: live, a block holds what arrived in ``LiveSource.batch_s`` (tens of
samples per joint), and that work costs mostly per call, not per sample. Every entry point that
changes the joint's state (a cycle's end, a discarded cycle, the end of the stream, a maintenance)
processes what is gathered first (so does the end of a stream that leaves its cycle open, via
:meth:`JointMonitor.catch_up`), so the order of events, and the symptoms, are those of unbatched
processing (the streaming algorithms are block-size invariant up to floating-point rounding). Reads
(counters, state snapshots) do not: they may lag by up to :data:`SAMPLE_BATCH` samples.
"""

from __future__ import annotations

import logging
import math
from dataclasses import replace
from typing import Any, Sequence

import numpy as np
from numpy.typing import NDArray

from edge_monitor.errors import StateMismatch
from edge_monitor.features.base import CycleInput, Feature
from edge_monitor.features.joint_model_learning import JointModelLearner
from edge_monitor.features.prognosis import JointPrognosis
from edge_monitor.features.registry import FEATURES, FeatureSpec
from edge_monitor.pipeline.agent_config import AgentConfig
from edge_monitor.pipeline.coverage import Coverage
from edge_monitor.pipeline.cycle_assembly import CycleAssembler
from edge_monitor.pipeline.detectors import Acknowledgement, DetectorBank
from edge_monitor.pipeline.fault_grouping import FaultTracker
from edge_monitor.pipeline.operating_range import OperatingRange, cycle_covariates
from edge_monitor.pipeline.pauses import PauseFinder
from edge_monitor.pipeline.temperature_source import TemperatureSource
from edge_monitor.pipeline.thermal_settling import ThermalSettling
from edge_monitor.records import Advisory, Alarm, Decision, Symptom, finite_or_none
from edge_monitor.stats.sequential_detector import Calibrator
from joint_model import FrictionParams

log = logging.getLogger(__name__)

#: Samples per joint gathered before the sample-level work runs (≈ 1 s at the simulator's rate).
SAMPLE_BATCH = 512


class _JointSettings:
    """What the feature builders read: the agent's config with this joint's learned model."""

    def __init__(self, config: AgentConfig, model: JointModelLearner | None) -> None:
        self.wear, self.kl = config.wear, config.kl
        self._config, self._model = config, model

    def friction_for(self, joint: int) -> FrictionParams:
        return self._model.params if self._model is not None else self._config.friction_for(joint)

    def temperature_relation(self, joint: int) -> tuple[float, float] | None:
        return self._model.relation if self._model is not None and self._model.learned else None

    def model_pending(self) -> bool:
        return self._model is not None and not self._model.learned


class JointMonitor:
    """All features and detectors of one joint (see the module docstring). The joint first learns
    its own friction model (:mod:`edge_monitor.features.joint_model_learning`); features that need it
    and the detectors start after that."""

    def __init__(self, joint: int, config: AgentConfig, calibrator: Calibrator | None = None) -> None:
        self.joint = joint
        self.config = config
        self.calibrator = calibrator
        self.assembler = CycleAssembler(joint, config.segmentation, config.rate_hz)
        self._pending: list[tuple[NDArray[np.int64], NDArray[np.float64], NDArray[np.float64], NDArray[np.int64]]] = []
        self._pending_samples = 0
        self.model = JointModelLearner(config.model, config.friction_for(joint), config.wear.default_load_mean,
                                       f"joint {joint} model") if config.model.enabled else None
        self.operating = OperatingRange()
        self.coverage = Coverage(self.detectors_watched)   # how much of the time each detector tests
        self.faults = FaultTracker(config.alarms, config.robot, joint)   # one alarm record per fault
        self.prognosis = self._new_prognosis()
        self.rate: Any = None           # the agent's cycle rate (``cycles_per_day``); None: the configured one
        self._build()
        self.maintenances = 0
        self.acknowledgements = 0          # alarms acknowledged (judged false) since the joint was first learned
        self.pauses = PauseFinder(config.rate_hz)   # where the joint stood still (the features are told)
        self.temperature_source = TemperatureSource()   # the motor's, or the friction's lubricant temperature

    def _build(self) -> None:
        """Features with the joint's current model, and fresh detectors (which keep the temperature
        history: a new model does not cool the joint)."""
        settings = _JointSettings(self.config, self.model)
        self.features: dict[str, Feature] = {spec.name: spec.build(self.joint, settings)
                                             for spec in FEATURES if spec.enabled(settings)}
        previous = self.__dict__.get("detectors")
        self.detectors = DetectorBank(self.config.decision, self._sources(), self.calibrator)
        if previous is not None:
            self.detectors.keep_settling(previous)

    @property
    def detectors_watched(self) -> list[str]:
        """The quantities this joint's detectors watch (none with the decision layer off)."""
        return list(self.config.decision.quantities) if self.config.decision.enabled else []

    def _new_prognosis(self) -> JointPrognosis | None:
        c = self.config
        return JointPrognosis(c.prognosis, c.critical_wear_for(self.joint)) if c.prognosis.enabled else None

    def retarget(self, arl0: float) -> int:
        """Every detector's threshold re-derived for ``arl0`` [cycles] (:meth:`DetectorBank.retarget`)."""
        return self.detectors.retarget(arl0)

    @property
    def model_ready(self) -> bool:
        return self.model is None or self.model.learned

    def _sources(self) -> dict[str, dict[str, Any]]:
        return {name: feature.state_dict().get("config", {}) for name, feature in self.features.items()}

    @property
    def cycles(self) -> int:
        """Cycles this joint has closed."""
        return self.assembler.closed

    # ------------------------------------------------------------------ streaming input
    def update(self, tick: NDArray[np.int64], speed: NDArray[np.float64], torque: NDArray[np.float64],
               segment: NDArray[np.int64] | None = None) -> list[Symptom]:
        """One block of this joint's samples in tick order (speed rad/s, torque fraction).

        ``segment`` is the controller's segment code per sample, or ``None`` when the controller
        sends no status frame; then the joint infers cycle boundaries itself and returns the symptoms
        of the cycles it closed.
        """
        if tick.size == 0:
            return []
        if segment is None:         # cycles are inferred from the samples: no gathering
            self._process_pending()
            return self._process(tick, speed, torque, None)
        self._pending.append((tick, speed, torque, segment))
        self._pending_samples += int(tick.size)
        if self._pending_samples >= SAMPLE_BATCH:
            self._process_pending()
        return []

    def catch_up(self) -> None:
        """Process the gathered samples now (the stream stops with its last cycle left open)."""
        self._process_pending()

    def _process_pending(self) -> None:
        """Run the sample-level work on the gathered blocks (see the module docstring). They all carry
        segment codes, so the controller closes their cycles and no symptom can come out of here."""
        if not self._pending:
            return
        parts, self._pending, self._pending_samples = self._pending, [], 0
        tick, speed, torque, segment = (np.concatenate(arrays) for arrays in zip(*parts))
        self._process(tick, speed, torque, segment)

    def _process(self, tick: NDArray[np.int64], speed: NDArray[np.float64], torque: NDArray[np.float64],
                 segment: NDArray[np.int64] | None) -> list[Symptom]:
        symptoms: list[Symptom] = []
        for part, pause in self.pauses.split(tick):
            if pause > 0:
                for feature in self.features.values():
                    feature.pause(pause)
                self.detectors.pause(pause)
            symptoms += self._process_run(tick[part], speed[part], torque[part],
                                          None if segment is None else segment[part])
        return symptoms

    def _process_run(self, tick: NDArray[np.int64], speed: NDArray[np.float64], torque: NDArray[np.float64],
                     segment: NDArray[np.int64] | None) -> list[Symptom]:
        symptoms = [self.update_cycle(cycle) for cycle in self.assembler.update(tick, speed, torque, segment)]
        for feature in self.features.values():
            feature.update_samples(torque, speed, segment)
        return symptoms

    def add_status(self, load_estimate: NDArray[np.float64], load_std: NDArray[np.float64],
                   motor_temperature: NDArray[np.float64]) -> None:
        """JointStatus frames of this joint in stream order (load estimate and σl dimensionless,
        motor temperature °C; one entry per frame)."""
        self.assembler.add_status(load_estimate, load_std, motor_temperature)

    def has_cycle_data(self) -> bool:
        """Whether the open cycle holds any friction data."""
        self._process_pending()
        return self.assembler.has_data()

    def flush(self) -> None:
        """End of stream: close a plateau still in progress."""
        self._process_pending()
        self.assembler.flush()

    def discard_cycle(self) -> None:
        """Drop the open cycle's data (a cycle already published before a restart)."""
        self._process_pending()
        self.assembler.discard_cycle()
        for feature in self.features.values():
            feature.discard_cycle()

    def end_cycle(self, cycle: int, partial: bool = False) -> Symptom:
        """Close the open cycle ``cycle``. A ``partial`` cycle (its beginning or its end was not seen) is published
        with its friction data and wear estimate but feeds neither learning nor the detectors."""
        self._process_pending()
        return self.update_cycle(self.assembler.end_cycle(cycle, partial))

    # ------------------------------------------------------------------ per-cycle pipeline
    def update_cycle(self, cycle: CycleInput) -> Symptom:
        """Features → detectors → symptom for one closed cycle of this joint."""
        robot = self.config.robot
        sections: dict[str, dict[str, Any]] = {}
        values: dict[str, float] = {}
        reasons: dict[str, str] = {}
        extras: dict[str, Any] = {}
        learning_model = not self.model_ready
        for spec in FEATURES:
            feature = self.features.get(spec.name)
            if feature is None or (learning_model and spec.waits_for_model):
                if feature is not None:
                    feature.discard_cycle()
                    reasons[spec.name] = self.model.progress if self.model is not None else ""
                sections[spec.name] = dict(spec.empty_section)
                values.update({q: float("nan") for q in spec.quantities})
                continue
            out = feature.update(cycle, values)
            sections[spec.name], extras = out.section, {**extras, **out.extras}
            values.update(out.values)
            if out.reason:
                reasons[spec.name] = out.reason
        self.detectors.observe_temperature(*self.joint_temperature(cycle, values))
        alarms: list[Alarm] = []
        advisories: list[Advisory] = []
        covariates = cycle_covariates(cycle)
        if learning_model and self.model is not None:
            decisions = self.detectors.idle(self.model.progress, coverage="model")
            if self.model.update(cycle):                    # this cycle completed the model: rebuild
                self._report_model("")
                self._build()
        elif cycle.partial:
            decisions = self.detectors.idle()
        else:
            collecting, fits = self.detectors.collecting, self.detectors.fits
            decisions, alarms = self.detectors.update(values, robot, self.joint, cycle.cycle)
            events = self.operating.update(covariates, collecting, self.detectors.fits > fits,
                                           usual=("motor_temperature",) if self.detectors.warming_up else ())
            advisories = [Advisory(robot, self.joint, cycle.cycle, "operating_range", e.state, e.covariate, e.value,
                                   e.learned) for e in events]
            alarms = [replace(a, cause=self._cause(decisions[a.quantity], covariates)) for a in alarms]
            alarms = self.faults.crossings(alarms, cycle.cycle)
        sections["operating"] = self.operating.section(covariates)
        self.coverage.update(self.detectors.reasons)
        sections["coverage"] = self.coverage.section(self.detectors.reasons)
        if self.prognosis is not None:
            sections["prognosis"], alarms, advisories = self._prognosis(cycle, sections.get("wear") or {}, decisions,
                                                                        alarms, advisories, learning_model)
        return Symptom(robot=robot, joint=self.joint, cycle=cycle.cycle, t=cycle.t,
                       friction=cycle.friction.to_record(), sections=sections, decisions=decisions,
                       load={"mean": finite_or_none(cycle.load_mean), "std": finite_or_none(cycle.load_std),
                             "measured": finite_or_none(cycle.friction.load_torque)},
                       skipped=cycle.friction.skipped, critical_wear=self.config.critical_wear_for(self.joint),
                       reasons=reasons, partial=cycle.partial, alarms=alarms, advisories=advisories, extras=extras)

    def _prognosis(self, cycle: CycleInput, wear: dict[str, Any], decisions: dict[str, Decision], alarms: list[Alarm],
                   advisories: list[Advisory], learning: bool) -> tuple[dict[str, Any], list[Alarm], list[Advisory]]:
        """This cycle's prognosis section (:mod:`edge_monitor.features.prognosis`), the alarm records carrying it,
        and the advisories with its early warning, if any."""
        assert self.prognosis is not None
        rate = self.config.decision.cycles_per_day if self.rate is None else self.rate.cycles_per_day
        forecast = self.prognosis.update(cycle.cycle, wear.get(self.config.prognosis.wear_input), wear.get("std"),
                                         use=not (learning or cycle.partial),
                                         alarm=any(d.alarm for d in decisions.values()), cycles_per_day=rate)
        section = forecast.section()
        warning = self.prognosis.warning_advisory(self.config.robot, self.joint, cycle.cycle, forecast)
        return section, [replace(a, prognosis=section) for a in alarms], advisories + ([warning] if warning else [])

    def joint_temperature(self, cycle: CycleInput, values: dict[str, float]) -> tuple[float | None, str]:
        """The temperature [°C] the detectors' stages, spans and slack follow, and what it is
        (:mod:`~edge_monitor.pipeline.temperature_source`). Called once per cycle, before the detectors' update."""
        lubricant = finite_or_none(values.get("temperature", math.nan)) if self.model_ready else None
        temperature, source, restart = self.temperature_source.pick(finite_or_none(cycle.motor_temperature), lubricant)
        if restart:
            log.info("joint %d: the controller now sends a motor temperature; the detectors' temperature "
                     "history read from the friction is restarted on it", self.joint)
            self.detectors.restart_temperature_history()
        return temperature, source

    def _cause(self, decision: Decision, covariates: dict[str, float | None]) -> dict[str, Any]:
        """An alarm's cause as far as the agent can tell: the shift in the quantity's units and the
        operating conditions against those learned (:mod:`~edge_monitor.pipeline.operating_range`)."""
        return {"delta": None if decision.delta is None else [finite_or_none(v) for v in decision.delta],
                "change_cycle": decision.change_cycle, "operating": self.operating.section(covariates)}

    def declare_maintenance(self, cycle: int, config: AgentConfig | None = None) -> list[Alarm]:
        """Gearbox replaced or serviced: relearn the nominal models; one "cleared" record closes the open fault.
        With ``config`` (the agent's current one) the relearned models use it, e.g. after models learned
        with a previous config were kept."""
        self._process_pending()
        cleared = self.faults.cleared(self.detectors.reset(self.config.robot, self.joint, cycle), cycle)
        if config is not None and config != self.config:
            counters = self.assembler.state_dict()
            self.config = config
            self.assembler = CycleAssembler(self.joint, config.segmentation, config.rate_hz)
            self.assembler.load_state(counters)
        self.faults.config = self.config.alarms
        cfg = self.config
        self.model = JointModelLearner(cfg.model, cfg.friction_for(self.joint), cfg.wear.default_load_mean,
                                       f"joint {self.joint} model") if cfg.model.enabled else None
        self._build()
        self.operating.reset()
        self.prognosis = self._new_prognosis()        # a new gearbox: its wear history starts again
        self.detectors.settling = ThermalSettling(self.config.decision.settling)   # it may have cooled meanwhile
        self.maintenances += 1
        return cleared

    def acknowledge(self, cycle: int, quantities: Sequence[str] | None = None) -> Acknowledgement:
        """An operator judged the latched alarms of ``quantities`` (default: all) false: those detectors
        restart their statistic on the same nominal and threshold (:meth:`DetectorBank.acknowledge`); one
        "acknowledged" record of their fault (:meth:`FaultTracker.acknowledged`)."""
        self._process_pending()
        result = self.detectors.acknowledge(self.config.robot, self.joint, cycle, quantities)
        latched = [q for q, d in self.detectors.detectors.items() if d.alarmed]
        result = replace(result, alarms=tuple(self.faults.acknowledged(result.alarms, cycle, latched)))
        self.acknowledgements += len(result.alarms)
        return result

    def counters(self) -> dict[str, Any]:
        """Segmentation counters of the samples processed so far (≤ SAMPLE_BATCH may still wait) and the
        detector-cycles held per quantity (docs/DETECTION.md, "Operating conditions")."""
        return {**self.assembler.counters(), "held": dict(self.detectors.held)}

    def coverage_summary(self) -> dict[str, Any]:
        """Per watched quantity: the share of cycles tested (overall and recent) and why not otherwise."""
        return self.coverage.summary()

    # ------------------------------------------------------------------ persistence
    def state_dict(self) -> dict[str, Any]:
        """Learned models, counters and the open cycle's KL window. A read without side effects (status
        ticks and state queries call it): samples still gathered are not in it, as samples after the
        snapshot are not; a cycle resumed from a saved state is published partial anyway."""
        return {"joint": self.joint, "config": self.config.fingerprint(self.joint),
                "maintenances": self.maintenances, "acknowledgements": self.acknowledgements,
                **self.temperature_source.state_dict(), "assembly": self.assembler.state_dict(),
                "pauses": self.pauses.state_dict(),
                "model": None if self.model is None else self.model.state_dict(),
                "features": {name: f.state_dict() for name, f in self.features.items()},
                "detectors": self.detectors.state_dict(), "operating": self.operating.state_dict(),
                "coverage": self.coverage.state_dict(),
                "faults": self.faults.state_dict(),
                "prognosis": None if self.prognosis is None else self.prognosis.state_dict()}

    @classmethod
    def from_state(cls, joint: int, config: AgentConfig, state: dict[str, Any],
                   calibrator: Calibrator | None = None) -> "JointMonitor":
        """A monitor with the learned models of ``state``. A component learned with another config is
        relearned and the change is logged as a warning; with ``on_config_change = "keep"`` the
        sections it was learned with are kept instead (also logged)."""
        saved = state.get("config")
        if config.on_config_change == "keep" and isinstance(saved, dict):
            config, kept = config.with_learned(joint, saved)
            if kept:
                log.warning("joint %d: keeping the models learned with the previous %s settings "
                            "(on_config_change = \"keep\"); the new settings apply after a maintenance "
                            "declaration or with on_config_change = \"relearn\"", joint, ", ".join(kept))
        monitor = cls(joint, config, calibrator)
        monitor.maintenances = int(state.get("maintenances", 0))
        monitor.acknowledgements = int(state.get("acknowledgements", 0))
        monitor.temperature_source = TemperatureSource.from_joint_state(state)
        monitor.pauses = PauseFinder.from_state(config.rate_hz, state.get("pauses"))
        assembly = state.get("assembly")
        if isinstance(assembly, dict):
            monitor.assembler.load_state(assembly)
        if monitor.model is not None and isinstance(state.get("model"), dict):
            monitor.model.load_state(state["model"])
            monitor._build()
        saved = state.get("features", {})
        for spec in FEATURES:
            if spec.name in monitor.features and isinstance(saved.get(spec.name), dict):
                monitor._restore_feature(spec, saved[spec.name])
        monitor.detectors = DetectorBank(config.decision, monitor._sources(), calibrator)
        for message in monitor.detectors.load_state(state.get("detectors", {}), joint):
            log.warning("%s", message)
        monitor.operating = OperatingRange.from_state(state.get("operating"))
        monitor.coverage = Coverage.from_state(monitor.detectors_watched, state.get("coverage"))
        monitor.faults = FaultTracker.from_state(config.alarms, config.robot, joint, state.get("faults"))
        monitor.faults.reconcile([q for q, d in monitor.detectors.detectors.items() if d.alarmed])
        monitor._restore_prognosis(state.get("prognosis"))
        monitor._report_model(" (learned before the restart)")
        return monitor

    def _report_model(self, when: str) -> None:
        """Log the learned joint model's warning, if it has one (see ``temperature_prior.implausible_offset``)."""
        warning = self.model.report.get("warning") if self.model is not None and self.model.learned else None
        if warning:
            log.warning("%s joint %d: joint model%s: %s", self.config.robot, self.joint, when, warning)

    def _restore_prognosis(self, state: Any) -> None:
        if self.prognosis is None or not isinstance(state, dict):
            return
        try:
            self.prognosis = JointPrognosis.from_state(self.config.prognosis, self.prognosis.critical_wear, state)
        except StateMismatch as exc:
            log.warning("joint %d: %s; the wear trend starts again", self.joint, exc)
        except (KeyError, TypeError, ValueError) as exc:
            log.warning("joint %d: saved wear trend unusable (%s); it starts again", self.joint, exc)

    def _restore_feature(self, spec: FeatureSpec, state: dict[str, Any]) -> None:
        try:
            self.features[spec.name] = spec.restore(self.joint, _JointSettings(self.config, self.model), state)
        except StateMismatch as exc:
            log.warning("joint %d: %s; relearning it", self.joint, exc)
        except (KeyError, TypeError, ValueError) as exc:
            log.warning("joint %d: saved %s state unusable (%s); relearning it", self.joint, spec.name, exc)
