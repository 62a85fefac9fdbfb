"""Per-joint monitor: chains plateau detection → friction extraction → wear estimation, the
streaming KDE/KL detector, and one sequential GLR detector per per-cycle quantity, and builds the
per-cycle symptom record of SYSTEM.md.

Per-joint memory is bounded: O(speed levels) + O(KDE grid) + O(GLR window · components).
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import NDArray

from edge_monitor.config import AgentConfig
from edge_monitor.records import SCHEMA_VERSION
from protocol.frames import SEGMENT_PRODUCTION
from edge_monitor.features.disturbance_weights import WeightFunction
from edge_monitor.features.friction_extraction import FrictionCurve, FrictionExtractor
from edge_monitor.features.kl_monitor import KLMonitor
from edge_monitor.features.segmentation import PlateauDetector
from edge_monitor.stats.sequential_detector import SequentialDetector
from edge_monitor.features.wear_estimation import WearEstimator

log = logging.getLogger(__name__)



def _finite_or_none(x: Any) -> float | None:
    try:
        f = float(x)
    except (TypeError, ValueError):
        return None
    return f if math.isfinite(f) else None


@dataclass
class CycleOutput:
    """What a joint produces at the end of a cycle: the symptom record (JSON-ready), alarm
    transitions, and extras for visualisation that are not part of the published record."""

    symptom: dict[str, Any]
    alarms: list[dict[str, Any]] = field(default_factory=list)
    extras: dict[str, Any] = field(default_factory=dict)


@dataclass
class _LoadAccumulator:
    """Mean of the controller's load estimates received during the cycle."""

    n: int = 0
    total: float = 0.0
    std: float = float("nan")

    def add(self, estimate: float, std: float) -> None:
        if math.isfinite(estimate):
            self.n += 1
            self.total += estimate
        if math.isfinite(std):
            self.std = std

    def mean(self) -> float:
        return self.total / self.n if self.n else float("nan")


class JointMonitor:
    """All detectors of one joint. Feed sample blocks and load estimates; call ``end_cycle``."""

    def __init__(self, joint: int, config: AgentConfig) -> None:
        self.joint = joint
        self.config = config
        self.plateaus = PlateauDetector(config.segmentation)
        self.extractor = FrictionExtractor(config.segmentation.speeds)
        self.wear = WearEstimator(params=config.friction_for(joint), noise_std=config.wear.noise_std,
                                  temperature_range=(config.wear.temperature_min, config.wear.temperature_max),
                                  method=config.wear.method)
        self.kl = self._new_kl_monitor() if config.kl.enabled else None
        self.detectors = {q: self._new_detector(q) for q in config.decision.quantities} \
            if config.decision.enabled else {}
        self._load = _LoadAccumulator()
        self._alarmed: dict[str, bool] = {}     # latched alarm per quantity (raised once, until maintenance)
        self._last_tick = 0
        self._cut_short_seen = 0
        self.cycles = 0
        self.maintenances = 0

    # ------------------------------------------------------------------ construction
    def _new_kl_monitor(self) -> KLMonitor:
        k = self.config.kl
        return KLMonitor(n_nominal_cycles=k.n_nominal_cycles, n_grid=k.n_grid,
                         weights=WeightFunction(alpha=k.alpha, beta=k.beta), window=k.window, center=k.center)

    def _new_detector(self, quantity: str) -> SequentialDetector:
        d = self.config.decision
        dim = 3 if quantity == "joint" else 1
        density = d.density_joint if quantity == "joint" else d.density
        pf = d.pf_joint if quantity == "joint" else d.pf
        return SequentialDetector(dim=dim, n_nominal=d.n_nominal, density=density, pf=pf, window=d.window,
                                  gamma0=d.gamma0, rho=d.rho)

    # ------------------------------------------------------------------ streaming input
    def add_samples(self, tick: NDArray[np.int64], speed: NDArray[np.float64], torque: NDArray[np.float64],
                    segment: NDArray[np.int64] | None = None) -> list[CycleOutput]:
        """One block of this joint's samples in tick order (speed rad/s, torque fraction).

        ``segment`` is the controller's segment code per sample, or ``None`` when the controller
        sends no status frame; then the joint infers cycle boundaries itself: a plateau of a
        (level, direction) already measured in the current cycle starts a new cycle, and the
        finished cycle's output is returned.
        """
        if tick.size == 0:
            return []
        outputs: list[CycleOutput] = []
        exclude = None if segment is None else (segment == SEGMENT_PRODUCTION)
        for plateau in self.plateaus.update(tick, speed, torque, exclude):
            if segment is None and self.extractor.has(plateau.level, plateau.direction):
                outputs.append(self.end_cycle(self.cycles, self.config.robot))
            self.extractor.update(plateau)
        if self.kl is not None:
            self.kl.add(torque, speed, segment)
        self._last_tick = int(tick[-1])
        return outputs

    def has_cycle_data(self) -> bool:
        """Whether the open cycle holds any friction data."""
        return self.extractor.n_pending > 0

    def plateaus_flush(self) -> None:
        """End of stream: close a plateau still in progress."""
        for plateau in self.plateaus.flush():
            self.extractor.update(plateau)

    def add_load_estimate(self, estimate: float, std: float) -> None:
        self._load.add(estimate, std)

    # ------------------------------------------------------------------ cycle end
    def discard_cycle(self) -> None:
        """Drop the open cycle's data (a cycle already published before a restart)."""
        self.extractor.end_cycle()
        if self.kl is not None:
            self.kl.discard_cycle()
        self._load = _LoadAccumulator()

    def end_cycle(self, cycle: int, robot: str, partial: bool = False) -> CycleOutput:
        """Close the cycle. A ``partial`` cycle (its beginning was not seen) is published with its
        friction data and wear estimate, but feeds neither KL learning nor the detectors."""
        cut = self.plateaus.counters.cut_short - self._cut_short_seen
        if cut:
            self.extractor.skip("plateau cut short", cut)
            self._cut_short_seen = self.plateaus.counters.cut_short
        curve = self.extractor.end_cycle()
        wear = self._estimate_wear(curve)
        kl = None
        if self.kl is not None:
            if partial:
                self.kl.discard_cycle()
            else:
                kl = self.kl.end_cycle(cycle)
        kl_record = self._kl_record(kl)
        kl_transform = _safe_log if self.config.decision.log_kl else (lambda x: x)
        values = {"wear": wear.estimate if wear is not None else float("nan"),
                  "kl_raw": kl_transform(_nan_if_none(kl_record["raw"])),
                  "kl_weighted": kl_transform(_nan_if_none(kl_record["weighted"]))}
        decisions, alarms = self._decide(values, cycle, robot) if not partial else (self._idle_decisions(), [])
        self.cycles += 1
        load_mean = self._load.mean()
        symptom: dict[str, Any] = {
            "schema": SCHEMA_VERSION, "robot": robot, "joint": self.joint, "cycle": cycle,
            "t": self._last_tick / self.config.rate_hz,
            "friction": curve.to_record(),
            "wear": wear.to_record() if wear is not None else {"estimate": None, "std": None, "temperature": None},
            "kl": kl_record,
            "decisions": decisions,
            "alarm": any(d.get("alarm") for d in decisions.values()),
            "load": {"mean": _finite_or_none(load_mean), "std": _finite_or_none(self._load.std)},
            "skipped": curve.skipped,
            "critical_wear": self.config.wear.critical,
        }
        reasons = {k: v for k, v in (("wear", getattr(wear, "reason", None)),
                                     ("kl", getattr(kl, "reason", None))) if v}
        if reasons:
            symptom["reasons"] = reasons
        extras: dict[str, Any] = {}
        density = getattr(kl, "density", None)
        if density is not None:
            extras["density"] = density
        self._load = _LoadAccumulator()
        return CycleOutput(symptom=symptom, alarms=alarms, extras=extras)

    @staticmethod
    def _kl_record(kl: Any) -> dict[str, Any]:
        """``kl`` field: raw/weighted (SYSTEM.md) plus the simple μ0 + 3σ0 thresholds, tail counts
        and the nearest stored mode when available."""
        if kl is None:
            return {"raw": None, "weighted": None}
        out: dict[str, Any] = {"raw": _finite_or_none(kl.raw), "weighted": _finite_or_none(kl.weighted)}
        if kl.threshold_3sigma:
            out["threshold_3sigma"] = {k: _finite_or_none(v) for k, v in kl.threshold_3sigma.items()}
        if kl.outside:
            out["outside"] = kl.outside
        if kl.nearest_mode is not None:
            out["nearest_mode"] = kl.nearest_mode
        out["n_samples"] = kl.n_samples
        return out

    def _estimate_wear(self, curve: FrictionCurve):
        if not self.config.wear.enabled:
            return None
        load_mean = self._load.mean()
        load_std = self._load.std if math.isfinite(self._load.std) else self.config.wear.default_load_std
        if not math.isfinite(load_mean):   # no JointStatus frame this cycle: the configured prior
            load_mean = self.config.wear.default_load_mean
        return self.wear.estimate(np.asarray(curve.speeds), np.asarray(curve.torque), load_mean, load_std,
                                  friction_stderr=np.asarray(curve.stderr) if curve.stderr else None)

    def _idle_decisions(self) -> dict[str, dict]:
        """Decision fields of a cycle that did not enter the detectors (state unchanged)."""
        return {q: {"state": d.state,
                    "statistic": None, "threshold": None, "alarm": self._alarmed.get(q, False),
                    "change_cycle": None, "delta": None, "miss_probability": None,
                    "reason": "partial cycle: not used by the detectors"}
                for q, d in self.detectors.items()}

    def _decide(self, values: dict[str, float], cycle: int, robot: str) -> tuple[dict, list]:
        decisions: dict[str, dict] = {}
        alarms: list[dict] = []
        for quantity, detector in self.detectors.items():
            if quantity == "joint":
                value: Any = [values["wear"], values["kl_raw"], values["kl_weighted"]]
            else:
                value = values[quantity]
            was_alarmed = self._alarmed.get(quantity, False)
            decision = detector.update(value, cycle)
            self._alarmed[quantity] = bool(decision.alarm)
            record = decision.to_record()
            if getattr(decision, "reason", None):
                record["reason"] = decision.reason
            decisions[quantity] = record
            if record.get("alarm") and not was_alarmed:
                alarms.append(self._alarm_record(robot, cycle, quantity, record, "raised"))
        return decisions, alarms

    def _alarm_record(self, robot: str, cycle: int, quantity: str, record: dict, state: str) -> dict:
        return {"schema": SCHEMA_VERSION, "robot": robot, "joint": self.joint, "cycle": cycle, "quantity": quantity,
                "state": state, "statistic": record.get("statistic"), "threshold": record.get("threshold"),
                "miss_probability": record.get("miss_probability"), "change_cycle": record.get("change_cycle")}

    def declare_maintenance(self, robot: str, cycle: int) -> list[dict]:
        """Gearbox replaced or serviced: relearn nominal models; clear raised alarms."""
        cleared = [self._alarm_record(robot, cycle, q, {}, "cleared")
                   for q in self.detectors if self._alarmed.get(q)]
        for det in self.detectors.values():
            det.reset()
        self._alarmed.clear()
        if self.kl is not None:
            self.kl.reset()
        self.maintenances += 1
        return cleared

    # ------------------------------------------------------------------ persistence
    def state_dict(self) -> dict[str, Any]:
        return {
            "joint": self.joint, "cycles": self.cycles, "alarmed": dict(self._alarmed),
            "maintenances": self.maintenances,
            "plateaus": self.plateaus.state_dict(), "extractor": self.extractor.state_dict(),
            "kl": self.kl.state_dict() if self.kl is not None else None,
            "detectors": {q: d.state_dict() for q, d in self.detectors.items()},
        }

    def load_state(self, state: dict[str, Any]) -> None:
        """Restore learned models and detector state (configuration comes from the current config)."""
        self.cycles = int(state.get("cycles", 0))
        self.maintenances = int(state.get("maintenances", 0))
        self._alarmed = {str(q): bool(v) for q, v in state.get("alarmed", {}).items()}
        self.plateaus = PlateauDetector.from_state(state.get("plateaus", {}), self.config.segmentation)
        self._cut_short_seen = self.plateaus.counters.cut_short
        if self.kl is not None and state.get("kl") is not None:
            self.kl = KLMonitor.from_state(state["kl"])
        for q, s in state.get("detectors", {}).items():
            if q in self.detectors:
                self.detectors[q] = SequentialDetector.from_state(s)


def _safe_log(x: float) -> float:
    """log of a KL distance for the detectors; non-positive or non-finite values become NaN (skipped)."""
    return math.log(x) if math.isfinite(x) and x > 0 else float("nan")


def _nan_if_none(x: Any) -> float:
    f = _finite_or_none(x)
    return float("nan") if f is None else f
