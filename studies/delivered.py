"""The delivered false-alarm rate against the stated one over a range of targets, from one replay.

Each healthy joint of the kept fleet series (:mod:`studies.series`: the default robots and the plant
weeks) is replayed through the agent's own :class:`DetectorBank` with a target so deep (10⁷ cycles) that
nothing alarms (a replay that does stops with an error). Every detector's GLR inputs are kept, per
nominal and stage; for each target T its threshold h(T) is read for the same nominal
and settings (the table, as the agent would), and the same GLR replays its inputs from fresh, restarted
at each alarm as an acknowledge restarts it (docs/DETECTION.md, "Delivered against stated, target by
target"). Delivered / stated = alarms · T / monitored cycles, per stage (warm-up, steady) and quantity,
with a 95 % Poisson interval. Not modelled: an acknowledge in the warm-up stage also drops the steady
values collected so far, which delays the steady stage.

One replay gives the whole curve, so the calibration is checked where alarms are many (10³–10⁴) as well
as at the budget's depth (≈ 5·10⁴), where a fleet of 30 robots gives a handful.

The command line is tools/studies/delivered_curve.py.
"""

from __future__ import annotations

import copy
import logging
import math
from dataclasses import dataclass, field, fields, replace
from typing import Any

import numpy as np
from numpy.typing import NDArray

from edge_monitor.config import config_from_mapping
from edge_monitor.stats.detector_config import CALIBRATION_KEYS
from edge_monitor.stats.glr import WindowedGLR
from studies.bank_replay import new_bank, replay_bank
from studies.robots import kept_robot_pauses
from studies.series import robot_series
from studies.settings import settings_from
from studies.statistics import poisson_interval

log = logging.getLogger(__name__)

#: The replay's own target: deep enough that no detector alarms, so no path is cut by an alarm.
REPLAY_ARL0 = 1.0e7
DEFAULT_TARGETS = (1.0e3, 3.0e3, 1.0e4, 3.0e4, 5.04e4)
DEFAULT_FLEET = tuple(range(101, 128))
DEFAULT_PLANT = (401, 402, 403)
#: The quantities a ``--variant`` re-thresholds: the scalars, whose Gaussian thresholds in standard units
#: are one simulation per setting (the joint vector's depend on each nominal's correlation: ≈ 4 s each).
VARIED = ("wear", "kl_raw", "kl_weighted")


@dataclass
class Tally:
    """Monitored cycles and false alarms per target (``crossings``: alarms, each followed by a restart),
    of one stage and quantity."""

    exposure: int = 0
    crossings: dict[float, int] = field(default_factory=dict)

    def merge(self, other: "Tally") -> None:
        self.exposure += other.exposure
        for t, n in other.crossings.items():
            self.crossings[t] = self.crossings.get(t, 0) + n


class ThresholdCache:
    """h(T) of calibration jobs at several targets T. A scalar Gaussian nominal's threshold does not depend on
    its values, only on their number and the settings (standard units, edge_monitor/stats/
    gaussian_calibration.py): those are computed once per process and setting."""

    def __init__(self) -> None:
        self._standard: dict[tuple[Any, ...], dict[float, float]] = {}

    def __len__(self) -> int:
        """Settings whose thresholds are kept."""
        return len(self._standard)

    def clear(self) -> None:
        self._standard.clear()

    def thresholds(self, job: Any, targets: tuple[float, ...]) -> dict[float, float]:
        """h(T) for a detector's calibration job (its nominal and settings) at each target T."""
        if not (job.kind == "gauss" and len(job.nominal[0]) == 1 and job.simulate_from == "model"):
            return {t: replace(job, arl0=t).run().threshold for t in targets}
        key = (len(job.nominal), targets,
               *sorted((k, v) for k, v in vars(job).items() if k not in ("nominal", "arl0")))
        if key not in self._standard:
            self._standard[key] = {t: replace(job, arl0=t).run().threshold for t in targets}
        return self._standard[key]


#: The process's threshold cache (:func:`replay_joint` reads it).
THRESHOLDS = ThresholdCache()


@dataclass
class StatisticPath:
    """What one detector's GLR was fed under one nominal and stage: its inputs, in order."""

    quantity: str
    stage: str
    job: Any
    glr: WindowedGLR
    inputs: list[NDArray[np.float64]] = field(default_factory=list)
    statistics: list[float] = field(default_factory=list)     # as the agent reported them (no alarm)

    def alarms(self, threshold: float) -> int:
        """False alarms at ``threshold``: the GLR from fresh over the same inputs, restarted at each alarm
        as an acknowledge restarts it (the statistic from 0, the same nominal)."""
        if not self.statistics or max(self.statistics) < threshold:
            return 0                          # up to its first alarm a restarted path is the recorded one
        glr = copy.deepcopy(self.glr)
        glr.restart()
        count = 0
        for y in self.inputs:
            if glr.update_statistic(y) >= threshold:
                count += 1
                glr.restart()
        return count


def statistic_paths(rows: list[dict[str, Any]], decision: Any,
                    pauses: dict[int, float] | None = None) -> list[StatisticPath]:
    """Every nominal of every detector of one joint's kept series, replayed through the agent's
    :class:`DetectorBank` (``decision`` should set a target no path reaches: no alarm cuts a path), the robot's
    stops (``pauses``: seconds before a cycle) seen as the agent sees them. A path's inputs are what its GLR
    took (``WindowedGLR.latest``), one per cycle that reached it."""
    bank = new_bank(decision)
    paths: list[StatisticPath] = []
    current: dict[str, StatisticPath] = {}
    taken: dict[int, tuple[WindowedGLR, int]] = {}          # id → (GLR, observations taken when last seen)
    for step in replay_bank(bank, rows, 0, "robot", pauses=pauses):
        for q, d in step.decisions.items():
            detector = bank.detectors[q]
            glr, job = detector.glr, detector.calibrated_job     # the GLR in use and its threshold's calibration
            if d.alarm:
                raise RuntimeError(f"the replay's {q} detector alarmed at cycle {step.cycle}: its target "
                                   f"({REPLAY_ARL0:g}) is too shallow for these settings, so the paths would "
                                   "not be the agent's")
            if glr is None:
                continue
            before = taken.get(id(glr), (glr, 0))[1]
            taken[id(glr)] = (glr, glr.count)
            if d.state != "monitoring" or d.statistic is None or job is None or glr.count == before:
                continue                                   # no observation reached the GLR this cycle
            stage = (d.calibration or {}).get("stage") or "warm-up"
            path = current.get(q)
            if path is None or path.glr is not glr or path.stage != stage:
                path = current[q] = StatisticPath(q, stage, job, glr)
                paths.append(path)
            latest = glr.latest
            assert latest is not None                      # the GLR has taken an observation
            path.inputs.append(latest)
            path.statistics.append(float(d.statistic))
    return paths


def variant_job(job: Any, stage: str, config: Any) -> Any:
    """``job`` calibrated as the detector ``config`` would for ``stage``: where its streams sit, their drift
    and wander (the statistic path does not depend on these, only its thresholds do)."""
    return replace(job, budget=config.budget, **config.calibration(stage))


#: The calibration fields a variant may change (:func:`variant_job` carries them to the job): where it
#: simulates, and how much it simulates where the table does not hold its settings.
CALIBRATION_FIELDS = (*CALIBRATION_KEYS, "calibration_draws", "calibration_steps", "arl0")


def check_variant(base: Any, variant: Any, name: str) -> None:
    """Refuse a variant that changes more than the scalar detectors' calibration: anything else would
    change the statistic paths, which a variant does not replay."""
    for q in VARIED:
        mine, theirs = base.detector_config(q), variant.detector_config(q)
        other = {f: getattr(theirs, f) for f in CALIBRATION_FIELDS}
        if replace(mine, **other) != theirs:
            changed = [f.name for f in fields(mine) if getattr(mine, f.name) != getattr(theirs, f.name)
                       and f.name not in CALIBRATION_FIELDS]
            raise ValueError(f"variant {name!r} changes {q}'s {', '.join(changed)}: a variant may only change "
                             f"where the calibration simulates ({', '.join(CALIBRATION_FIELDS[:-1])}); "
                             "run the tool with --set for anything else")


def replay_joint(rows: list[dict[str, Any]], decision: Any, targets: tuple[float, ...],
                 variants: dict[str, Any] | None = None, pauses: dict[int, float] | None = None) -> dict[str, Tally]:
    """``stage/quantity`` → Tally for one joint's kept series, thresholds as ``decision`` calibrates them;
    ``variants`` (name → another DecisionConfig) add ``name:stage/quantity`` tallies of the same paths
    against the thresholds that config's calibration gives; ``pauses`` as :func:`statistic_paths` takes them."""
    tallies: dict[str, Tally] = {}
    for path in statistic_paths(rows, decision, pauses):
        jobs = {"": path.job}
        for name, config in (variants or {}).items() if path.quantity in VARIED else ():
            jobs[f"{name}:"] = variant_job(path.job, path.stage, config.detector_config(path.quantity))
        for prefix, job in jobs.items():
            tally = tallies.setdefault(f"{prefix}{path.stage}/{path.quantity}", Tally())
            tally.exposure += len(path.inputs)
            for t, level in THRESHOLDS.thresholds(job, targets).items():
                tally.crossings[t] = tally.crossings.get(t, 0) + path.alarms(level)
    return tallies


def replay_robot(job: tuple[Any, ...]) -> dict[str, Tally]:
    """All joints of one kept robot (seed, cycles, scenario, overrides, targets, variants; the variants as
    :func:`check_variant` accepts them)."""
    seed, cycles, scenario, overrides, targets, variants = job
    replay = overrides + (("decision.arl0_cycles", REPLAY_ARL0),)
    decision = config_from_mapping(settings_from(replay)).decision
    configs = {name: config_from_mapping(settings_from(replay + extra)).decision for name, extra in variants}
    out: dict[str, Tally] = {}
    stops = kept_robot_pauses(seed, cycles, scenario)
    for joint, rows in robot_series(seed, cycles, 6, scenario).items():
        try:
            tallies = replay_joint(rows, decision, targets, configs, stops)
        except RuntimeError as exc:            # say which robot and joint (a healthy path beyond 10⁷)
            raise RuntimeError(f"seed {seed} joint {joint}: {exc}; leave that robot out (--fleet, --plant) "
                               "to measure the others") from None
        for key, tally in tallies.items():
            out.setdefault(key, Tally()).merge(tally)
    log.info("seed %d done", seed)
    return out


def summary(tallies: dict[str, Tally], targets: tuple[float, ...]) -> list[dict[str, Any]]:
    """Rows per stage/quantity and per stage (``stage/all``): crossings, due, ratio and its interval."""
    pooled: dict[str, Tally] = {}
    for key, tally in tallies.items():
        pooled.setdefault(key, Tally()).merge(tally)
        pooled.setdefault(key.split("/")[0] + "/all", Tally()).merge(tally)
    rows = []
    for key in sorted(pooled):
        tally = pooled[key]
        for t in targets:
            k, due = tally.crossings.get(t, 0), tally.exposure / t
            lo, hi = poisson_interval(k, due) if due > 0 else (math.nan, math.nan)
            rows.append({"group": key, "target": t, "exposure": tally.exposure, "crossings": k, "due": due,
                         "ratio": k / due if due > 0 else math.nan, "ratio_95": [lo, hi]})
    return rows
