"""The delivered false-alarm rate against the stated one over a range of targets, from one replay.

Each healthy joint of the kept fleet series (``tools/studies/fleet_series.py``: the default robots and the plant
weeks) is replayed through the agent's own :class:`DetectorBank` with a target so deep (10⁷ cycles) that
nothing alarms (a replay that does stops with an error). Every detector's GLR inputs are kept, per
nominal and stage; for each target T of ``--targets`` its threshold h(T) is read for the same nominal
and settings (the table, as the agent would), and the same GLR replays its inputs from fresh, restarted
at each alarm as an acknowledge restarts it (docs/DETECTION.md, "Delivered against stated, target by
target"). Delivered / stated = alarms · T / monitored cycles, per stage (warm-up, steady) and quantity,
with a 95 % Poisson interval. Not modelled: an acknowledge in the warm-up stage also drops the steady
values collected so far, which delays the steady stage.

One replay gives the whole curve, so the calibration is checked where alarms are many (10³–10⁴) as well
as at the budget's depth (≈ 5·10⁴), where a fleet of 30 robots gives a handful.

    python tools/studies/delivered_curve.py --json out.json            # 27 default robots + 3 plant weeks, ≈ 5 min
    python tools/studies/delivered_curve.py --variant 'old:decision.steady_drift={"kl_raw":[0.10,0.09]}'
"""

from __future__ import annotations

import argparse
import copy
import json
import logging
import math
import sys
from collections.abc import Iterator
from concurrent.futures import ProcessPoolExecutor
from contextlib import contextmanager
from dataclasses import dataclass, field, fields, replace
from pathlib import Path
from typing import Any

sys.path.insert(0, str(Path(__file__).resolve().parent))

import numpy as np  # noqa: E402
from numpy.typing import NDArray  # noqa: E402
from scipy.stats import chi2  # noqa: E402

from edge_monitor.config import config_from_mapping  # noqa: E402
from edge_monitor.pipeline.detectors import DetectorBank  # noqa: E402
from edge_monitor.stats.detector_config import CALIBRATION_KEYS  # noqa: E402
from edge_monitor.stats.glr import WindowedGLR  # noqa: E402

log = logging.getLogger("delivered_curve")

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


#: Thresholds of scalar Gaussian jobs by everything but their nominal's values (see :func:`_thresholds`).
_STANDARD: dict[tuple[Any, ...], dict[float, float]] = {}


def _thresholds(job: Any, targets: tuple[float, ...]) -> dict[float, float]:
    """h(T) for a detector's calibration job (its nominal and settings) at each target T. A scalar Gaussian
    nominal's threshold does not depend on its values, only on their number and the settings (standard
    units, edge_monitor/stats/gaussian_calibration.py): computed once per process for those."""
    if not (job.kind == "gauss" and len(job.nominal[0]) == 1 and job.simulate_from == "model"):
        return {t: replace(job, arl0=t).run().threshold for t in targets}
    key = (len(job.nominal), targets, *sorted((k, v) for k, v in vars(job).items() if k not in ("nominal", "arl0")))
    if key not in _STANDARD:
        _STANDARD[key] = {t: replace(job, arl0=t).run().threshold for t in targets}
    return _STANDARD[key]


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


@contextmanager
def _recorded_glr_inputs() -> Iterator[dict[int, tuple[WindowedGLR, list[NDArray[np.float64]]]]]:
    """Every observation any :class:`WindowedGLR` is fed while inside, per GLR (id → (GLR, inputs))."""
    fed: dict[int, tuple[WindowedGLR, list[NDArray[np.float64]]]] = {}
    original = WindowedGLR.update

    def update(self: WindowedGLR, y: Any) -> Any:
        fed.setdefault(id(self), (self, []))[1].append(np.array(y, dtype=float))
        return original(self, y)

    WindowedGLR.update = update  # type: ignore[method-assign]
    try:
        yield fed
    finally:
        WindowedGLR.update = original  # type: ignore[method-assign]


def statistic_paths(rows: list[dict[str, Any]], decision: Any) -> list[StatisticPath]:
    """Every nominal of every detector of one joint's kept series, replayed through the agent's
    :class:`DetectorBank` (``decision`` should set a target no path reaches: no alarm cuts a path)."""
    bank = DetectorBank(decision, {})
    paths: list[StatisticPath] = []
    current: dict[str, StatisticPath] = {}
    with _recorded_glr_inputs() as fed:
        for row in rows:
            bank.observe_temperature(row.get("motor_temperature"))
            before = {id(g): len(inputs) for g, inputs in fed.values()}
            decisions, _ = bank.update(row, "robot", 0, int(row["cycle"]))
            for q, d in decisions.items():
                detector = bank.detectors[q]
                glr = getattr(detector, "_glr", None)
                job = getattr(detector, "_done", None) or getattr(detector, "_job", None)   # its calibration
                if d.alarm:
                    raise RuntimeError(f"the replay's {q} detector alarmed at cycle {row['cycle']}: its target "
                                       f"({REPLAY_ARL0:g}) is too shallow for these settings, so the paths would "
                                       "not be the agent's")
                if d.state != "monitoring" or d.statistic is None or glr is None or job is None:
                    continue
                inputs = fed.get(id(glr), (glr, []))[1]
                if len(inputs) == before.get(id(glr), 0):
                    continue                                   # no observation reached the GLR this cycle
                stage = (d.calibration or {}).get("stage") or "warm-up"
                path = current.get(q)
                if path is None or path.glr is not glr or path.stage != stage:
                    path = current[q] = StatisticPath(q, stage, job, glr)
                    paths.append(path)
                path.inputs.append(inputs[-1])
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
                 variants: dict[str, Any] | None = None) -> dict[str, Tally]:
    """``stage/quantity`` → Tally for one joint's kept series, thresholds as ``decision`` calibrates them;
    ``variants`` (name → another DecisionConfig) add ``name:stage/quantity`` tallies of the same paths
    against the thresholds that config's calibration gives."""
    tallies: dict[str, Tally] = {}
    for path in statistic_paths(rows, decision):
        jobs = {"": path.job}
        for name, config in (variants or {}).items() if path.quantity in VARIED else ():
            jobs[f"{name}:"] = variant_job(path.job, path.stage, config.detector_config(path.quantity))
        for prefix, job in jobs.items():
            tally = tallies.setdefault(f"{prefix}{path.stage}/{path.quantity}", Tally())
            tally.exposure += len(path.inputs)
            for t, level in _thresholds(job, targets).items():
                tally.crossings[t] = tally.crossings.get(t, 0) + path.alarms(level)
    return tallies


def replay_robot(job: tuple[Any, ...]) -> dict[str, Tally]:
    """All joints of one kept robot (seed, cycles, scenario, overrides, targets, variants; the variants as
    :func:`check_variant` accepts them)."""
    from fleet_series import robot_series
    from healthy_fleet_study import settings_from

    seed, cycles, scenario, overrides, targets, variants = job
    replay = overrides + (("decision.arl0_cycles", REPLAY_ARL0),)
    decision = config_from_mapping(settings_from(replay)).decision
    configs = {name: config_from_mapping(settings_from(replay + extra)).decision for name, extra in variants}
    out: dict[str, Tally] = {}
    for joint, rows in robot_series(seed, cycles, 6, scenario).items():
        try:
            tallies = replay_joint(rows, decision, targets, configs)
        except RuntimeError as exc:            # say which robot and joint (a healthy path beyond 10⁷)
            raise RuntimeError(f"seed {seed} joint {joint}: {exc}; leave that robot out (--fleet, --plant) "
                               "to measure the others") from None
        for key, tally in tallies.items():
            out.setdefault(key, Tally()).merge(tally)
    log.info("seed %d done", seed)
    return out


def poisson_interval(k: int, mean: float) -> tuple[float, float]:
    """95 % interval of the ratio k / mean for a Poisson count k."""
    lo = chi2.ppf(0.025, 2 * k) / 2 if k else 0.0
    return lo / mean, chi2.ppf(0.975, 2 * k + 2) / 2 / mean


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


def parse_variant(text: str) -> tuple[str, tuple[tuple[str, Any], ...]]:
    """``"NAME:decision.steady_drift={…};decision.allowance=0.5"`` → (NAME, settings)."""
    from healthy_fleet_study import parse_set

    name, sep, rest = text.partition(":")
    if not sep or not name or not rest:
        raise argparse.ArgumentTypeError(f"expected NAME:TABLE.KEY=VALUE[;…], got {text!r}")
    return name, tuple(parse_set(item) for item in rest.split(";") if item.strip())


def main(argv: list[str] | None = None) -> int:
    from healthy_fleet_study import parse_set, settings_from

    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--fleet", type=int, nargs="*", default=list(DEFAULT_FLEET), help="default robots (1 100 cycles)")
    p.add_argument("--plant", type=int, nargs="*", default=list(DEFAULT_PLANT), help="plant weeks (4 400 cycles)")
    p.add_argument("--targets", type=float, nargs="+", default=list(DEFAULT_TARGETS))
    p.add_argument("--set", dest="overrides", action="append", default=[], type=parse_set, metavar="TABLE.KEY=VALUE")
    p.add_argument("--variant", action="append", default=[], type=parse_variant, metavar="NAME:TABLE.KEY=VALUE;…",
                   help="also count the same paths against the thresholds these settings calibrate")
    p.add_argument("--jobs", type=int, default=2)
    p.add_argument("--json", type=Path)
    args = p.parse_args(argv)
    logging.basicConfig(level=logging.INFO, format="%(asctime)s %(message)s", datefmt="%H:%M:%S")
    targets = tuple(args.targets)
    overrides = tuple(args.overrides)
    variants = tuple(args.variant)
    try:
        base = config_from_mapping(settings_from(overrides)).decision
        for name, extra in variants:           # once, here: a refused variant is a message, not a worker's traceback
            check_variant(base, config_from_mapping(settings_from(overrides + extra)).decision, name)
    except ValueError as exc:                  # ConfigError is a ValueError too
        print(f"delivered_curve: {exc}", file=sys.stderr)
        return 2
    jobs = [(s, 1100, None, overrides, targets, variants) for s in args.fleet] + \
           [(s, 4400, "plant_week", overrides, targets, variants) for s in args.plant]
    total: dict[str, Tally] = {}
    try:
        with ProcessPoolExecutor(max_workers=max(1, args.jobs)) as pool:
            for result in pool.map(replay_robot, jobs):
                for key, tally in result.items():
                    total.setdefault(key, Tally()).merge(tally)
    except RuntimeError as exc:                # a replay that alarmed (statistic_paths)
        print(f"delivered_curve: {exc}", file=sys.stderr)
        return 2
    rows = summary(total, targets)
    for r in rows:
        lo, hi = r["ratio_95"]
        print(f"{r['group']:24s} T={r['target']:>8.0f}  {r['crossings']:5d} / {r['due']:8.1f} due  "
              f"delivered/stated {r['ratio']:5.2f} (95 % {lo:.2f}–{hi:.2f})")
    if args.json:
        args.json.write_text(json.dumps({"fleet": args.fleet, "plant": args.plant, "targets": targets,
                                         "overrides": dict(overrides), "rows": rows}, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
