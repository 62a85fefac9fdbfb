"""Every joint its own model: the joint's nominal friction parameters, identified from its first cycles.

Joints of one robot differ (the simulator's default: ±8 % on nine parameters) and the §1 table is one
joint's. During its first ``learning_cycles`` cycles a joint collects its friction curves, the
controller's load estimates and motor temperatures; then it identifies (docs/ALGORITHMS.md §1):

* the lubricant temperature of each learning cycle, ξk, which is not measured: the best fit of the
  nominal model to that cycle's friction curve (wear 0), alternating with
* the parameters the data can tell, with the others fixed at the base table, by regression towards
  the base table: the maximum a posteriori estimate under a Gaussian prior of ``prior_relative_std``
  (:func:`joint_model.identification.identify_linear`; plain least squares fitted the load estimate's
  noise at the lowest speeds into fs0 and extrapolated it badly to warm lubricant,
  docs/WEAR_ESTIMATION.md §5): always the speed-level terms fc0 (Coulomb), fs0 (Stribeck) and fv0
  (viscous); the temperature coefficients fsξ, fvξ only when the ξk (and the motor temperatures'
  10–90 % range, where known) span at least ``temperature_span`` °C (a cold start warms a joint by a
  few °C in 20 cycles: not enough); the load coefficients fcl, fsl only when the spread of the load
  estimates exceeds twice their own noise (otherwise the noise of the regressor biases them). A
  parameter whose least-squares standard error exceeds ``max_relative_std`` of its value keeps the
  base value (judged by the data alone: the prior would make every one look certain). Nonlinear
  parameters keep the base values.
* how the motor temperature of JointStatus relates to ξk (offset and spread of ξ ≈ motor
  temperature − offset; :mod:`edge_monitor.features.temperature_prior`).

What it falls back on: the base parameters (``[friction]`` / ``[joint.N.friction]``) for whatever is
not identified, and no temperature prior without motor temperatures. Maintenance relearns it all.
"""

from __future__ import annotations

import logging
import math
from dataclasses import asdict, dataclass, replace
from typing import Any

import numpy as np

from edge_monitor.errors import require
from edge_monitor.features.base import MEASURED_LOAD_STD, CycleInput, cycle_load
from edge_monitor.features.temperature_prior import MIN_SPREAD, implausible_offset
from joint_model import FrictionParams, nominal_friction
from joint_model.identification import CommissioningData, IdentificationDataError, identify_linear

log = logging.getLogger(__name__)
#: Whole cycles in a row without a friction curve after which a learning joint says so (then every 1000).
STARVED_WARN_AT = (5, 50, 500)

ALWAYS_FREE: tuple[str, ...] = ("fc0", "fs0", "fv0")
TEMPERATURE_TERMS: tuple[str, ...] = ("fsxi", "fvxi")
LOAD_TERMS: tuple[str, ...] = ("fcl", "fsl")
#: The load regressor's noise [fraction of max torque] when it is the controller's estimate (σl ≈ 0.1 in the
#: simulator); a measured load's is :data:`~edge_monitor.features.base.MEASURED_LOAD_STD`.
ESTIMATED_LOAD_NOISE = 0.1
#: Alternations of (per-cycle temperatures ↔ parameters).
ALTERNATIONS = 3
#: Temperature grid of the per-cycle fit [°C].
_GRID = np.arange(20.0, 90.0001, 0.1)


@dataclass(frozen=True)
class ModelConfig:
    """Per-joint model learning (the ``[model]`` table), validated once, here."""

    enabled: bool = True
    learning_cycles: int = 20
    temperature_span: float = 15.0       # °C of ξk spread needed to identify fsξ and fvξ
    max_relative_std: float = 0.5        # a parameter less certain than this keeps its base value
    prior_relative_std: float = 0.05     # 1 σ of a joint's parameters around the base table (relative)

    def __post_init__(self) -> None:
        require(isinstance(self.learning_cycles, int) and 5 <= self.learning_cycles <= 10_000,
                "model.learning_cycles", f"must be 5 … 10000 cycles, got {self.learning_cycles!r}")
        require(math.isfinite(self.temperature_span) and self.temperature_span > 0, "model.temperature_span",
                f"must be > 0 °C, got {self.temperature_span}")
        require(math.isfinite(self.max_relative_std) and self.max_relative_std > 0, "model.max_relative_std",
                f"must be > 0, got {self.max_relative_std}")
        require(math.isfinite(self.prior_relative_std) and self.prior_relative_std > 0, "model.prior_relative_std",
                f"must be > 0 (1e6: practically no prior, least squares), got {self.prior_relative_std}")

    def fingerprint(self) -> dict[str, Any]:
        return asdict(self)


@dataclass
class _Cycle:
    speeds: list[float]
    friction: list[float]
    load: float
    motor: float | None          # the cycle's motor temperature [°C]
    measured: bool = False       # ``load`` measured at the test cycle's plateaus (else the controller's estimate)


class JointModelLearner:
    """Collects the first cycles of a joint and identifies its model (see the module docstring)."""

    def __init__(self, config: ModelConfig, base: FrictionParams, default_load: float = 0.5,
                 label: str = "joint model") -> None:
        self.config = config
        self.base = base
        self.default_load = default_load
        self.label = label                   # the log's name for it ("joint 3 model")
        self._starved = 0                    # whole cycles in a row without a friction curve (not saved)
        self.reset()

    def reset(self) -> None:
        self.params: FrictionParams = self.base
        self.learned = False
        self.relation: tuple[float, float] | None = None    # (offset, spread) of ξ vs motor temperature [°C]
        self.report: dict[str, Any] = {}
        self._cycles: list[_Cycle] = []
        self._motor: float | None = None

    @property
    def progress(self) -> str:
        return f"learning the joint's friction model {len(self._cycles)}/{self.config.learning_cycles}"

    def update(self, cycle: CycleInput) -> bool:
        """Collect one learning cycle; True when this cycle completed the learning."""
        if self.learned:
            return False
        ok = cycle.motor_temperature is not None and math.isfinite(cycle.motor_temperature)
        self._motor = cycle.motor_temperature if ok else None
        curve = cycle.friction
        if len(curve.speeds) < 2 or cycle.partial:
            self._starved += not cycle.partial
            if not cycle.partial and (self._starved in STARVED_WARN_AT or self._starved % 1000 == 0):
                skipped = ", ".join(f"{why} {n}" for why, n in sorted(curve.skipped.items())) or "none"
                log.warning("%s: %d whole cycles in a row gave no friction curve (fewer than 2 speed levels; skipped: "
                            "%s), so it learns nothing: check that the plateaus last longer than [segmentation] "
                            "settle_s + min_steady_s and that the speeds are those configured", self.label,
                            self._starved, skipped)
            return False
        self._starved = 0
        load, measured = self._load(cycle)
        self._cycles.append(_Cycle(list(curve.speeds), list(curve.torque), load, self._motor, measured))
        if len(self._cycles) < self.config.learning_cycles:
            return False
        self._identify()
        return True

    def _load(self, cycle: CycleInput) -> tuple[float, bool]:
        """The cycle's |τl| (:func:`~edge_monitor.features.base.cycle_load`, else the default load) and
        whether it was measured at the plateaus."""
        found = cycle_load(cycle)
        return (self.default_load, False) if found is None else (found[0], found[1] == "measured")

    # ------------------------------------------------------------------ identification
    def _temperatures(self, params: FrictionParams) -> np.ndarray:
        """Per cycle, the lubricant temperature whose nominal curve fits the cycle best [°C]."""
        out = np.empty(len(self._cycles))
        for k, c in enumerate(self._cycles):
            v, tau = np.asarray(c.speeds), np.asarray(c.friction)
            model = nominal_friction(v[None, :], c.load, _GRID[:, None], params)
            out[k] = _GRID[int(np.argmin(np.sum((tau[None, :] - model) ** 2, axis=1)))]
        return out

    def _data(self, temperatures: np.ndarray) -> CommissioningData:
        rows = [(v, t, c.load, f) for c, t in zip(self._cycles, temperatures) for v, f in zip(c.speeds, c.friction)]
        speed, temperature, load, friction = (np.array(col, dtype=float) for col in zip(*rows))
        return CommissioningData(speed=speed, temperature=temperature, load=load, friction=friction)

    def _span(self, temperatures: np.ndarray) -> float:
        """The learning cycles' spread of lubricant temperature [°C]: the fitted ξk's range, and where
        motor temperatures are known no more than their 10–90 % range (with few speeds per cycle the ξk
        are noisy and their range is mostly noise; a real warm-up moves the motor too)."""
        span = float(np.ptp(temperatures))
        motor = [c.motor for c in self._cycles if c.motor is not None]
        if len(motor) >= max(5, len(self._cycles) // 2):
            span = min(span, float(np.subtract(*np.percentile(motor, [90, 10]))))
        return span

    def _free(self, temperatures: np.ndarray) -> tuple[str, ...]:
        free = ALWAYS_FREE
        if self._span(temperatures) >= self.config.temperature_span:
            free += TEMPERATURE_TERMS
        loads = np.array([c.load for c in self._cycles])
        noise = MEASURED_LOAD_STD if all(c.measured for c in self._cycles) else ESTIMATED_LOAD_NOISE
        if loads.var() > 4 * noise ** 2:       # the regressor's own noise would bias them otherwise
            free += LOAD_TERMS
        return free

    def _certain(self, data: CommissioningData, free: tuple[str, ...]) -> tuple[str, ...]:
        """The parameters of ``free`` that the data alone (least squares, no prior) pin down to within
        ``max_relative_std`` of their value; the others keep the base value. Judged without the prior,
        which would make every parameter look certain: with 2–4 speeds per cycle (a designed
        experiment) nothing is, and the joint keeps the base table."""
        plain = identify_linear(data, self.base, free)
        return tuple(n for n, sd in plain.std_errors.items()
                     if sd <= self.config.max_relative_std * max(abs(getattr(plain.params, n)), 1e-12))

    def _identify(self) -> None:
        params, free, prior = self.base, ALWAYS_FREE, self.config.prior_relative_std
        temperatures = self._temperatures(params)
        told: dict[str, float] = {}
        try:
            for _ in range(ALTERNATIONS):
                data = self._data(temperatures)
                free = self._certain(data, self._free(temperatures))
                told = {}
                params = self.base
                if free:
                    result = identify_linear(data, self.base, free, prior)
                    params = result.params
                    told = {n: _data_share(result.std_errors[n], prior * abs(getattr(self.base, n))) for n in free}
                temperatures = self._temperatures(params)
        except (IdentificationDataError, np.linalg.LinAlgError, ValueError) as exc:
            log.warning("joint model identification failed (%s); keeping the base parameters", exc)
            params, free, told = self.base, (), {}
        self.params = params
        self.relation = self._motor_relation(temperatures)
        self.learned = True
        self.report = {"identified": list(free), "cycles": len(self._cycles),
                       "temperature_span": float(np.ptp(temperatures)),
                       "parameters": {n: getattr(params, n) for n in free},
                       "data_share": told,
                       "motor_offset": None if self.relation is None else self.relation[0],
                       "warning": None if self.relation is None else implausible_offset(*self.relation)}
        self._cycles = []
        log.info("joint model learned: %s identified over %.1f °C (share of the data against the prior %s), "
                 "motor offset %s", list(free), self.report["temperature_span"],
                 {n: round(v, 2) for n, v in told.items()}, self.report["motor_offset"])

    def _motor_relation(self, temperatures: np.ndarray) -> tuple[float, float] | None:
        pairs = [(c.motor, t) for c, t in zip(self._cycles, temperatures) if c.motor is not None]
        if len(pairs) < max(5, len(self._cycles) // 2):
            return None
        residual = np.array([m - t for m, t in pairs])
        offset = float(np.median(residual))
        return offset, max(MIN_SPREAD, 1.4826 * float(np.median(np.abs(residual - offset))))

    # ------------------------------------------------------------------ persistence
    def state_dict(self) -> dict[str, Any]:
        return {"config": self.config.fingerprint(), "base": self.base.to_dict(), "learned": self.learned,
                "params": self.params.to_dict(), "relation": None if self.relation is None else list(self.relation),
                "report": self.report, "motor": self._motor,
                "cycles": [asdict(c) for c in self._cycles]}

    def load_state(self, state: dict[str, Any]) -> None:
        """Restore what was learned (with the same base parameters; otherwise relearn)."""
        if state.get("base") != self.base.to_dict() or state.get("config") != self.config.fingerprint():
            log.warning("joint model: base parameters or [model] settings changed since it was learned; relearning")
            return
        self.learned = bool(state.get("learned"))
        if self.learned:
            self.params = replace(self.base, **{k: float(v) for k, v in state["params"].items()
                                                if k in self.base.to_dict()})
            relation = state.get("relation")
            self.relation = None if relation is None else (float(relation[0]), float(relation[1]))
            self.report = dict(state.get("report", {}))
        motor = state.get("motor")
        self._motor = float(motor) if isinstance(motor, (int, float)) else None
        self._cycles = [_Cycle(**c) for c in state.get("cycles", [])]


def _data_share(posterior_std: float, prior_std: float) -> float:
    """How much of a parameter's estimate the data decided: 1 − posterior variance / prior variance
    (0: the prior alone, the base value; 1: the data alone)."""
    if prior_std <= 0:
        return 0.0
    return float(min(1.0, max(0.0, 1.0 - (posterior_std / prior_std) ** 2)))
