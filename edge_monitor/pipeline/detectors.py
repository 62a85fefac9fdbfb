"""The decision layer of one joint: one sequential detector per watched quantity (docs/ALGORITHMS.md §6).

:class:`~edge_monitor.pipeline.decision_config.DecisionConfig` (the ``[decision]`` table) says which
registered quantities are watched and how; :class:`DetectorBank` turns the feature values of a cycle
into one :class:`Decision` per quantity and the alarm transitions of that cycle. Positive, right-skewed
quantities (the KL distances) are watched as their logarithm when ``log_scale`` is on; the wear is
watched as its likelihood-ratio score; a vector quantity is made of its inputs' (transformed) values.
Detectors look for an increase by default: wear and KL distances grow with a fault, a decrease is
nominal.
"""

from __future__ import annotations

import logging
import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

from edge_monitor.errors import StateMismatch
from edge_monitor.features.registry import LOG_SCALE, QUANTITIES, QuantitySpec, feature_of
from edge_monitor.pipeline.coverage import coverage_reason
from edge_monitor.pipeline.decision_config import (  # noqa: F401  (re-exported: the [decision] table lives there)
    BUDGET_PERIODS,
    DEFAULT_CYCLES_PER_DAY,
    DEFAULT_JOINTS_PER_ROBOT,
    MAX_JOINTS_PER_ROBOT,
    SCHEDULE_KEYS,
    DecisionConfig,
)
from edge_monitor.pipeline.healthy_drift import (  # noqa: F401  (re-exported: the decision tables live there)
    HEALTHY_DRIFT,
    STEADY_DRIFT,
    STEADY_WANDER,
)
from edge_monitor.pipeline.hold_temperature import HoldTemperature
from edge_monitor.pipeline.nominal_temperature import FRICTION_TEMPERATURE, MOTOR_TEMPERATURE, NominalSpans
from edge_monitor.pipeline.thermal_settling import ThermalSettling
from edge_monitor.records import Alarm, Decision, finite_or_none
from edge_monitor.stats.detector_config import DEFAULT_NOMINAL, DetectorConfig  # noqa: F401  (DEFAULT_NOMINAL re-exported)
from edge_monitor.stats.sequential_detector import Calibrator, SequentialDetector

log = logging.getLogger(__name__)

#: Key of the thermal settling tracker in the detectors' state (not a quantity name).
SETTLING_KEY = "_thermal_settling"
#: Key of the motor-temperature spans the nominals were learned in (not a quantity name), and its name in
#: states saved before the warm-up detectors kept theirs.
SPANS_KEY, OLD_SPANS_KEY = "_nominal_temperature", "_steady_temperature"
#: Key of the smoothed temperature the holds read (not a quantity name).
HOLD_KEY = "_hold_temperature"
#: Key of the temperature the detectors are calibrated for (not a quantity name; absent: the motor temperature).
CALIBRATED_FOR_KEY = "_calibrated_for"

#: Reason of the decisions of a cycle that is kept out of the detectors.
PARTIAL_REASON = "partial cycle: not used by the detectors"



def _log_or_nan(x: float) -> float:
    """log of a positive finite value; NaN otherwise (the detector skips and counts it)."""
    return math.log(x) if math.isfinite(x) and x > 0 else math.nan


@dataclass(frozen=True)
class Acknowledgement:
    """What :meth:`DetectorBank.acknowledge` did: one "acknowledged" alarm per quantity whose latched
    alarm it cleared, and the quantities asked for that had no latched alarm (left unchanged)."""

    alarms: tuple[Alarm, ...]
    not_latched: tuple[str, ...]


class DetectorBank:
    """The detectors of one joint. ``sources`` maps each feature name to the fingerprint of what its
    values depend on: a detector learned on values of another feature configuration is relearned."""

    def __init__(self, config: DecisionConfig, sources: dict[str, dict[str, Any]],
                 calibrator: Calibrator | None = None) -> None:
        self.config = config
        self.sources = sources
        self.calibrator = calibrator
        self.detectors = {q: SequentialDetector(config.detector_config(q), calibrator)
                          for q in config.quantities} if config.enabled else {}
        self.settling = ThermalSettling(config.settling)
        self.temperature: float | None = None         # the current cycle's temperature [°C] (observe_temperature)
        self.hold_temperature = HoldTemperature()      # its smoothing, which the spans and holds read
        self.smoothed: float | None = None            # the current cycle's smoothed temperature [°C] (holds)
        self.temperature_source = MOTOR_TEMPERATURE
        self.calibrated_for = MOTOR_TEMPERATURE        # the temperature the detectors' calibrations assume
        self.spans = NominalSpans(warm_up_hold=config.warm_up_hold,   # the temperatures of the nominals (holds)
                                  warm_margin=config.warm_up_hold_margin, warm_side=config.steady_relearn,
                                  slack_prior=config.temperature_slack)
        self.held: dict[str, int] = {}      # detector-cycles held per quantity (health, not persisted)
        self.reasons: dict[str, str] = {}   # this cycle's coverage reason per quantity (pipeline/coverage.py)
        self.after_pause = (0, 0.0)         # (cycles still held, the pause [s]) after a pause (:meth:`pause`)

    def observe_temperature(self, temperature: float | None, source: str = MOTOR_TEMPERATURE) -> None:
        """A cycle's mean temperature [°C] (None: unknown), ``source`` saying which (the motor's, or the
        lubricant's read from the friction). Once the joint's temperature has settled, every detector still on
        its warm-up nominal learns its steady one; if it warms again before a detector has collected its
        steady values, that collection is dropped. A stop (the temperature jumps,
        :class:`~edge_monitor.pipeline.hold_temperature.HoldTemperature`) restarts the settling test: the
        joint warms again from where the stop left it."""
        self.temperature = finite_or_none(temperature)
        self.temperature_source = source
        self._calibrate_for(source)
        stops = self.hold_temperature.stops
        self.smoothed = self.hold_temperature.update(self.temperature)
        if self.hold_temperature.stops > stops:        # a stop: the warming starts over, so does the settling
            self.settling = ThermalSettling(self.config.settling)
        settled = self.settling.update(self.temperature)
        for quantity, detector in self.detectors.items():
            if settled and self.config.steady_relearn:
                learning = detector.state == "learning" and detector.stage != "steady"
                detector.begin_steady()
                if learning and detector.stage == "steady":       # learns again from settled values only
                    self.spans.restart(quantity)
            elif not settled:
                detector.cancel_steady()      # warming again: the values collected are not steady

    def _detector_config(self, quantity: str) -> DetectorConfig:
        return self.config.detector_config(quantity, friction_temperature=self.calibrated_for == FRICTION_TEMPERATURE)

    def _calibrate_for(self, source: str) -> None:
        """Calibrations for the temperature the detectors follow: a joint without motor temperature has its own
        warm-up law (``decision.warm_up_law_friction``). On a change, a detector whose settings differ re-derives its
        threshold on the same nominal, learned with the other ``decision.learned_sd_prior_friction`` or not (a detector
        not yet learned just takes them, and fits its nominal with the new prior)."""
        if source == self.calibrated_for:
            return
        self.calibrated_for = source
        for quantity, detector in self.detectors.items():
            config = self._detector_config(quantity)
            if config != detector.config:      # a nominal learned with the other sd prior is kept as learned
                carried = {**detector.state_dict(), "config": config.fingerprint()}
                self.detectors[quantity] = SequentialDetector.from_state(config, carried, self.calibrator)

    def keep_settling(self, previous: "DetectorBank") -> None:
        """Carry ``previous``'s temperature history over (the joint was rebuilt, not cooled), and its count of
        held detector-cycles (a health counter of the run)."""
        self.settling = ThermalSettling.from_state(self.config.settling, previous.settling.state_dict())
        self.hold_temperature = HoldTemperature.from_state(previous.hold_temperature.state_dict())
        self.held = dict(previous.held)
        for quantity, detector in self.detectors.items():           # and the budget's current target
            if quantity in previous.detectors:
                detector.retarget(previous.detectors[quantity].arl0)

    def restart_temperature_history(self) -> None:
        """The joint's temperature now comes from another source: settling and the nominals' spans start over
        (no hold until a nominal is learned again)."""
        self.settling = ThermalSettling(self.config.settling)
        self.hold_temperature = HoldTemperature()
        self.spans.clear()

    def retarget(self, arl0: float) -> int:
        """Re-derive every threshold for the mean run length ``arl0`` [cycles] on the same nominals (the
        robot's cycle rate changed, :mod:`~edge_monitor.pipeline.cycle_rate`); calibrations started."""
        return sum(detector.retarget(arl0) for detector in self.detectors.values())

    def watched(self, values: dict[str, float]) -> dict[str, float]:
        """Feature values in the units the detectors watch (log of the log-scale quantities; NaN for a
        log-scale value that is not positive and finite)."""
        return {q: _log_or_nan(v) if self.config.log_scale and q in LOG_SCALE else v for q, v in values.items()}

    def update(self, values: dict[str, float], robot: str, joint: int, cycle: int
               ) -> tuple[dict[str, Decision], list[Alarm]]:
        """Feed one cycle's feature values (NaN when missing); decisions and raised alarms."""
        watched = self.watched(values)
        decisions: dict[str, Decision] = {}
        alarms: list[Alarm] = []
        self.reasons = {}
        for quantity, detector in self.detectors.items():
            spec = QUANTITIES[quantity]
            value = [watched.get(q, math.nan) for q in spec.inputs]
            fed = value[0] if spec.dim == 1 else value
            was_alarmed, collecting, fits = detector.alarmed, detector.collecting, detector.fits
            learning = detector.state == "learning"
            settling = self._pause_hold(spec, detector)
            held = settling or self.spans.held(quantity, detector, self.smoothed, self.temperature_source)
            if held:
                self.held[quantity] = self.held.get(quantity, 0) + 1
            slack = None if held else self.spans.slack(quantity, spec.inputs, detector, self.smoothed)
            decision = detector.idle(held) if settling else detector.collect(fed, cycle, held) if held else \
                detector.update(fed, cycle, slack)
            if decision.statistic is not None and not held:
                self.spans.learn(quantity, spec.inputs, detector, value, self.smoothed)
            self.reasons[quantity] = coverage_reason(decision, learning, all(map(math.isfinite, value)), held)
            self.spans.track(quantity, detector, collecting, detector.fits > fits, self._span_temperature)
            decisions[quantity] = decision
            if decision.alarm and not was_alarmed:       # the crossing's numbers (it may have come while calibrating)
                crossing = detector.crossing or {}
                statistic = crossing.get("statistic", decision.statistic)
                change = crossing.get("change_cycle", decision.change_cycle)
                alarms.append(Alarm(robot, joint, cycle, quantity, "raised", statistic, decision.threshold,
                                    decision.miss_probability, change))
        self.after_pause = (max(0, self.after_pause[0] - 1), self.after_pause[1])
        return decisions, alarms

    def pause(self, seconds: float) -> None:
        """The joint stood still for ``seconds`` before its next samples. After a pause of at least
        ``decision.pause_hold_min_h`` the monitoring detectors of the KL distances (and the joint vector) hold for
        the next ``decision.pause_hold_cycles`` cycles: the KL temperature compensation predicts how far the joint
        cooled, and its estimate settles on the cycles' own lubricant temperature within a few cycles."""
        if self.config.pause_hold_cycles > 0 and seconds >= 3600.0 * self.config.pause_hold_min_h:
            self.after_pause = (self.config.pause_hold_cycles, float(seconds))

    def _pause_hold(self, spec: QuantitySpec, detector: SequentialDetector) -> str:
        """The reason ``spec``'s detector holds this cycle after a pause ("" if it does not)."""
        left, seconds = self.after_pause
        if left <= 0 or detector.state != "monitoring" or not any(q in LOG_SCALE for q in spec.inputs):
            return ""
        done = self.config.pause_hold_cycles - left + 1
        return (f"held: cycle {done} of {self.config.pause_hold_cycles} after a {seconds / 3600:.1f} h pause (the KL "
                f"temperature compensation settles on the cooled joint)")

    @property
    def _span_temperature(self) -> float | None:
        """What this cycle adds to a span being collected: the smoothed temperature, not a jump awaiting
        confirmation (one wild reading would widen a span for good)."""
        return self.smoothed if self.hold_temperature.confirmed else None

    @property
    def warming_up(self) -> bool:
        """Whether the joint is on its first warming path: a detector monitors on its warm-up nominal (the
        temperature slack covers what the joint's temperature does meanwhile)."""
        return any(d.state == "monitoring" and d.stage == "warm-up" for d in self.detectors.values())

    @property
    def collecting(self) -> bool:
        """Whether any detector is collecting the values of a nominal (learning, or steady values)."""
        return any(d.collecting for d in self.detectors.values())

    @property
    def fits(self) -> int:
        """Nominals fitted by the detectors so far (grows when one is learned)."""
        return sum(d.fits for d in self.detectors.values())

    def idle(self, reason: str = PARTIAL_REASON, coverage: str = "partial") -> dict[str, Decision]:
        """Decisions of a cycle that did not enter the detectors (state unchanged); ``coverage``: why, as
        :mod:`~edge_monitor.pipeline.coverage` counts it (``partial`` or ``model``)."""
        self.reasons = dict.fromkeys(self.detectors, coverage)
        return {q: d.idle(reason) for q, d in self.detectors.items()}

    def reset(self, robot: str, joint: int, cycle: int) -> list[Alarm]:
        """Declared maintenance: every detector relearns; one "cleared" alarm per latched quantity."""
        cleared = [Alarm(robot, joint, cycle, q, "cleared") for q, d in self.detectors.items() if d.alarmed]
        for detector in self.detectors.values():
            detector.reset()
        self.spans.clear()
        return cleared

    def acknowledge(self, robot: str, joint: int, cycle: int,
                    quantities: Sequence[str] | None = None) -> Acknowledgement:
        """An operator judged the latched alarms of ``quantities`` (default: every watched one) false:
        each latched detector clears its alarm and restarts its statistic on the same nominal and
        threshold (no relearning, unlike :meth:`reset`); a later crossing raises a new alarm. One
        "acknowledged" alarm per cleared quantity; a detector without a latched alarm is left as it is
        and named in ``not_latched``. ``ValueError`` (nothing changed) for a quantity not watched here."""
        names = list(self.detectors) if quantities is None else list(dict.fromkeys(quantities))
        unknown = [q for q in names if q not in self.detectors]
        if unknown:
            raise ValueError(f"joint {joint}: quantity {', '.join(map(repr, unknown))} is not watched; "
                             f"watched: {', '.join(self.detectors) or 'none (decision layer off)'}")
        latched = [q for q in names if self.detectors[q].alarmed]
        for quantity in latched:
            self.detectors[quantity].acknowledge()
        events = tuple(Alarm(robot, joint, cycle, q, "acknowledged", threshold=self.detectors[q].threshold)
                       for q in latched)
        return Acknowledgement(events, tuple(q for q in names if q not in latched))

    # ------------------------------------------------------------------ persistence
    def _fingerprint(self, quantity: str) -> dict[str, Any]:
        spec = QUANTITIES[quantity]
        features = sorted({feature_of(q) for q in spec.inputs})
        return {"log": self.config.log_scale and spec.log_scale, "inputs": list(spec.inputs),
                "sources": {f: self.sources.get(f, {}) for f in features}}

    def state_dict(self) -> dict[str, Any]:
        out = {q: {**d.state_dict(), "inputs": self._fingerprint(q)} for q, d in self.detectors.items()}
        return {**out, SETTLING_KEY: self.settling.state_dict(), SPANS_KEY: self.spans.state_dict(),
                HOLD_KEY: self.hold_temperature.state_dict(), CALIBRATED_FOR_KEY: self.calibrated_for}

    def _check_inputs(self, quantity: str, saved: Any) -> None:
        """:class:`StateMismatch` naming what changed if ``quantity``'s detector learned on other values."""
        current = self._fingerprint(quantity)
        if saved == current:
            return
        saved = saved if isinstance(saved, dict) else {}
        changes: dict[str, tuple[object, object]] = {}
        if saved.get("inputs") != current["inputs"]:
            changes["quantity inputs"] = (saved.get("inputs"), current["inputs"])
        if saved.get("log") != current["log"]:
            changes["decision.log_scale"] = (saved.get("log"), current["log"])
        for feature, settings in current["sources"].items():
            if saved.get("sources", {}).get(feature) != settings:
                changes[f"{feature} settings"] = ("learned", "changed")
        raise StateMismatch(f"detector {quantity}", changes or {"inputs": ("learned", "changed")})

    def load_state(self, state: dict[str, Any], joint: int) -> list[str]:
        """Restore detectors from ``state``; a detector whose settings or inputs changed since it was
        learned starts learning again. Returns one message per relearned detector."""
        messages: list[str] = []
        self.calibrated_for = FRICTION_TEMPERATURE if state.get(CALIBRATED_FOR_KEY) == FRICTION_TEMPERATURE \
            else MOTOR_TEMPERATURE
        if isinstance(state.get(SETTLING_KEY), dict):
            self.settling = ThermalSettling.from_state(self.config.settling, state[SETTLING_KEY])
        self.hold_temperature = HoldTemperature.from_state(state.get(HOLD_KEY)) if HOLD_KEY in state else \
            HoldTemperature.replayed(self.settling.recent())      # saved before the holds smoothed
        self.spans = NominalSpans.from_state(state.get(SPANS_KEY, state.get(OLD_SPANS_KEY)), self.config.warm_up_hold,
                                             self.config.warm_up_hold_margin, self.config.steady_relearn,
                                             self.config.temperature_slack,
                                             {q: QUANTITIES[q].inputs for q in self.detectors})
        for quantity in self.detectors:
            saved = state.get(quantity)
            if saved is None:
                self.spans.forget(quantity)
                continue
            try:
                self._check_inputs(quantity, saved.get("inputs"))
                self.detectors[quantity] = SequentialDetector.from_state(self._detector_config(quantity), saved,
                                                                         self.calibrator)
            except StateMismatch as exc:
                self.spans.forget(quantity)
                messages.append(f"joint {joint}: {exc}; relearning the {quantity} detector")
        return messages


__all__ = ["Acknowledgement", "DecisionConfig", "DetectorBank", "PARTIAL_REASON", "QuantitySpec"]
