"""Validating the prognosis like a prognostics result (Saxena et al., "Metrics for evaluating performance
of prognostic techniques", PHM 2008; docs/PROGNOSIS.md): the agent's :class:`JointPrognosis` replayed
on the recorded inputs of simulated joints (:mod:`studies.prognosis_fleet`), against the
true end of life.

Per wearing joint, from its first alarm t_P (detection starts prognosis) to its end of life EoL (the
first cycle at critical wear), every cycle's forecast of the remaining life RUL = EoL − t:

* **coverage**: the share of forecasts whose 10–90 % band holds the true RUL (a forecast without a band —
  no trend, or a band past the grid — does not hold it; one whose 90 % point lies past the grid holds every
  RUL above its 10 % point);
* **α–λ accuracy** (α = 0.2, λ = 0.5): the median at t_λ = t_P + λ·(EoL − t_P) within ±α of the true RUL;
* **relative accuracy** at λ: 1 − |RUL − median| / RUL (a forecast without a median scores 0);
* **prognostic horizon**: EoL − the first cycle from which every median stays within ±α·(EoL − t_P) of the
  true RUL, as a share of EoL − t_P (0: never).

Per healthy joint: the share of its cycles (after learning) whose forecast is "beyond the horizon", and
the early warnings it gave (false by construction).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Iterable, Sequence

import numpy as np

from edge_monitor.features.prognosis import Forecast, JointPrognosis, PrognosisConfig
from edge_monitor.pipeline.cycle_rate import BudgetRate
from edge_monitor.pipeline.decision_config import DecisionConfig
from joint_model import CRITICAL_WEAR
from studies.prognosis_fleet import CycleRow

ALPHA = 0.2
LAMBDA = 0.5


@dataclass(frozen=True)
class ForecastRow:
    """The part of one cycle's forecast the metrics read: the cycle, its state, (p10, median, p90) in
    cycles (None: no band), beyond the horizon, and whether an early warning was on."""

    cycle: int
    state: str
    band: tuple[float | None, float | None, float | None] | None
    beyond_horizon: bool
    warning: bool


def replay(rows: Sequence[CycleRow], config: PrognosisConfig, decision: DecisionConfig | None = None,
           critical: float = CRITICAL_WEAR, forecast_from: int = 0) -> list[ForecastRow]:
    """The prognosis of one joint over its recorded rows, as the agent computes it: fed while the joint's
    model is not learning and the cycle is complete, days at the rate the agent measures from the rows'
    controller time (``decision.cycles_per_day`` until a day is counted). Forecasts of the cycles before
    ``forecast_from`` are not computed (their trend updates are: a study that reads only later ones
    saves the time)."""
    prognosis, rate = JointPrognosis(config, critical), BudgetRate(decision or DecisionConfig())
    out = []
    for row in rows:
        use = not (row.learning or row.partial)
        wear = getattr(row, config.wear_input)
        if row.cycle < forecast_from:
            prognosis.trend.update(row.cycle, wear if use else None, row.std if use else None)
            rate.update(row.t)
            continue
        forecast = prognosis.update(row.cycle, wear, row.std, use=use, alarm=row.alarm,
                                    cycles_per_day=rate.cycles_per_day)
        rate.update(row.t)
        prognosis.warning_change(forecast)
        out.append(_row(row.cycle, forecast, prognosis.warning))
    return out


def _row(cycle: int, forecast: Forecast, warning: bool) -> ForecastRow:
    return ForecastRow(cycle, forecast.state, forecast.cycles, forecast.beyond_horizon, warning)


@dataclass
class WearScore:
    """The metrics of one wearing joint (see the module docstring); None where undefined (no alarm)."""

    law: str
    end_of_life: int
    first_alarm: int | None
    forecasts: int = 0
    covered: int = 0
    alpha_lambda: bool | None = None
    relative_accuracy: float | None = None
    horizon_share: float | None = None
    alarm_wear: float | None = None

    @property
    def coverage(self) -> float | None:
        return self.covered / self.forecasts if self.forecasts else None


def first_alarm(rows: Sequence[CycleRow]) -> CycleRow | None:
    """The first row with an alarm latched, or None."""
    return next((r for r in rows if r.alarm), None)


def covers(f: ForecastRow, rul: float) -> bool:
    """Whether the 10–90 % band of ``f`` holds ``rul`` [cycles] (a missing 90 % point: the band reaches beyond
    the grid; a missing 10 % point or no band: it does not hold a finite life)."""
    if f.band is None or f.state != "forecast" or f.band[0] is None:
        return False
    return f.band[0] <= rul and (f.band[2] is None or rul <= f.band[2])


def _median(f: ForecastRow) -> float | None:
    """The median remaining life [cycles] of ``f``: 0 once critical, None without a forecast."""
    if f.state == "critical":
        return 0.0
    return None if f.band is None or f.state != "forecast" else f.band[1]


def score_wearing(law: str, rows: Sequence[CycleRow], forecasts: Sequence[ForecastRow],
                  critical: float = CRITICAL_WEAR) -> WearScore:
    """The metrics of one wearing joint from its rows (with the true wear) and its forecasts."""
    end = next((r.cycle for r in rows if r.wear >= critical), None)
    if end is None:
        raise ValueError(f"{law}: the joint never reaches the critical wear {critical:g} in its rows")
    alarm = first_alarm(rows)
    score = WearScore(law, end, None if alarm is None or alarm.cycle >= end else alarm.cycle)
    if score.first_alarm is None:
        return score
    score.alarm_wear = alarm.wear if alarm is not None else None
    t_p = score.first_alarm
    after = [f for f in forecasts if t_p <= f.cycle < end]
    for f in after:
        rul = end - f.cycle
        score.forecasts += 1
        score.covered += covers(f, rul)
    t_lambda = t_p + LAMBDA * (end - t_p)
    at = min(after, key=lambda f: abs(f.cycle - t_lambda)) if after else None
    if at is not None:
        rul, median = end - at.cycle, _median(at)
        score.alpha_lambda = median is not None and abs(median - rul) <= ALPHA * rul
        score.relative_accuracy = 0.0 if median is None else max(0.0, 1.0 - abs(rul - median) / rul)
    bound, inside_from = ALPHA * (end - t_p), None
    for f in after:
        median = _median(f)
        ok = median is not None and abs(median - (end - f.cycle)) <= bound
        inside_from = (f.cycle if inside_from is None else inside_from) if ok else None
    score.horizon_share = 0.0 if inside_from is None else (end - inside_from) / (end - t_p)
    return score


def score_joint(law: str, rows: Sequence[CycleRow], config: PrognosisConfig) -> WearScore:
    """The metrics of one wearing joint under ``config``: its prognosis replayed from its first alarm."""
    alarm = first_alarm(rows)
    forecasts = replay(rows, config, forecast_from=alarm.cycle if alarm else len(rows))
    return score_wearing(law, rows, forecasts)


def cell(value: float | None, spec: str) -> str:
    """A table cell: ``value`` formatted by ``spec``, "–" for none."""
    return "–" if value is None else format(value, spec)


@dataclass
class HealthyScore:
    """One healthy joint: cycles after learning, of which beyond the horizon, and early warnings."""

    cycles: int = 0
    beyond: int = 0
    warnings: int = 0
    states: dict[str, int] = field(default_factory=dict)

    @property
    def beyond_share(self) -> float | None:
        return self.beyond / self.cycles if self.cycles else None


def score_healthy(forecasts: Iterable[ForecastRow]) -> HealthyScore:
    out, was_on = HealthyScore(), False
    for f in forecasts:
        out.states[f.state] = out.states.get(f.state, 0) + 1
        if f.state == "learning":
            continue
        out.cycles += 1
        out.beyond += f.beyond_horizon
        out.warnings += f.warning and not was_on
        was_on = f.warning
    return out


def law_table(scores: Sequence[WearScore]) -> dict[str, dict[str, float | int | None]]:
    """Per law (and "all"): joints, joints alarmed, coverage over the pooled forecasts, α–λ pass share,
    mean relative accuracy at λ, median prognostic horizon share, median true wear at the first alarm."""
    out: dict[str, dict[str, float | int | None]] = {}
    laws = sorted({s.law for s in scores}, key=[s.law for s in scores].index)
    for law in laws + ["all"]:
        group = [s for s in scores if law in ("all", s.law)]
        alarmed = [s for s in group if s.first_alarm is not None]
        forecasts = sum(s.forecasts for s in alarmed)
        judged = [s for s in alarmed if s.alpha_lambda is not None]
        out[law] = {
            "joints": len(group), "alarmed": len(alarmed),
            "coverage": sum(s.covered for s in alarmed) / forecasts if forecasts else None,
            "alpha_lambda": sum(bool(s.alpha_lambda) for s in judged) / len(judged) if judged else None,
            "relative_accuracy": _mean([s.relative_accuracy for s in judged]),
            "horizon_share": _median_of([s.horizon_share for s in alarmed]),
            "alarm_wear": _median_of([s.alarm_wear for s in alarmed]),
        }
    return out


def _mean(values: Sequence[float | None]) -> float | None:
    kept = [v for v in values if v is not None]
    return float(np.mean(kept)) if kept else None


def _median_of(values: Sequence[float | None]) -> float | None:
    kept = [v for v in values if v is not None and math.isfinite(v)]
    return float(np.median(kept)) if kept else None


#: Laws whose last event is a straight line (what the oracle fit below assumes).
STRAIGHT_LAWS = ("linear", "step_ramp", "rate_change")


def oracle_line(law: str, last_start: int, rows: Sequence[CycleRow], critical: float = CRITICAL_WEAR
                ) -> tuple[float, float, float] | None:
    """The best a trend model of the right shape can do with these estimates: a straight line fitted by
    least squares to the estimates from the start of the law's last (straight) event up to t_λ, the law
    and its start known. Returns (true RUL, its median, relative error) at t_λ, or None (no alarm, not a
    straight law)."""
    end = next((r.cycle for r in rows if r.wear >= critical), None)
    alarm = first_alarm(rows)
    if law not in STRAIGHT_LAWS or end is None or alarm is None or alarm.cycle >= end:
        return None
    t_lambda = round(alarm.cycle + LAMBDA * (end - alarm.cycle))
    points = np.array([(r.cycle, r.estimate) for r in rows if last_start <= r.cycle <= t_lambda
                       and r.estimate is not None and not (r.learning or r.partial)], dtype=float)
    slope, intercept = np.polyfit(points[:, 0], points[:, 1], 1)
    rul = end - t_lambda
    median = (critical - (intercept + slope * t_lambda)) / slope if slope > 0 else math.inf
    return float(rul), float(median), abs(median - rul) / rul
