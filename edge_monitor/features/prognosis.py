"""Prognosis of one joint: when its wear reaches the critical level, with a band (docs/PROGNOSIS.md).

Each cycle the joint's wear estimate and its std feed a recursive trend model
(:mod:`edge_monitor.stats.wear_trend`); its crossing-time distribution gives the cycles until the
critical wear (median and the 10–90 % band), in days at the cycle rate the agent measures, and the
probability of reaching it within each configured horizon. The ``prognosis`` section of the symptom:

* ``learning`` — the joint's friction model or the trend's first ``learning_cycles`` estimates;
* ``no_trend`` — no growing wear found: the joint's detectors have no alarm latched (with
  ``after_alarm``, the default: detection starts prognosis) or the rate is not ``trend_sigma`` of its
  standard deviations above 0 (for the multi-rate model: in its best-fitting filter). The probabilities
  are then those of the current level alone (no growth);
* ``forecast`` — a trend: the band, or ``beyond_horizon`` when its median lies past the longest horizon
  (no number is published then: a "35 years" from a rate near zero is noise, not a forecast);
* ``critical`` — the filtered wear is at or above the critical level.

An optional early warning (``warning_probability`` > 0) reports when P(critical within
``warning_horizon_days``) first reaches that level and when it has stayed below half of it for
:data:`WARNING_CLEAR_CYCLES` cycles.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, fields
from typing import Any

import numpy as np

from edge_monitor.errors import require
from edge_monitor.records import Advisory, is_finite_number
from edge_monitor.stats.crossing_time import horizon_grid, probability_within, quantiles
from edge_monitor.stats.wear_trend import TrendConfig, WearTrend, new_trend, trend_from_state

STATES = ("learning", "no_trend", "forecast", "critical")
#: Band probabilities of the published forecast: 10 %, median, 90 %.
BAND = (0.1, 0.5, 0.9)
#: The horizon grid reaches this many times the longest horizon (in cycles) [-].
GRID_REACH = 20.0
#: The early warning is "left" once the probability has stayed below half its level this many cycles in a
#: row (as an operating-range advisory: a forecast that comes and goes does not page every few cycles).
WARNING_CLEAR_CYCLES = 20
#: What the trend can be fed each cycle, keys of the wear section (docs/OUTPUTS.md): the maximum-likelihood
#: ``estimate`` or the ``posterior_mean`` under the flat prior; both with the posterior ``std``.
WEAR_INPUTS = ("estimate", "posterior_mean")


@dataclass(frozen=True)
class PrognosisConfig:
    """The ``[prognosis]`` table, validated once, here; the trend model's own settings are
    :class:`~edge_monitor.stats.wear_trend.TrendConfig`'s (same names). Horizons in days."""

    enabled: bool = True
    model: str = "multi_rate"
    rate_drift: float = 1e-5
    acceleration_drift: float = 1e-12
    level_diffusion: float = 1e-3
    initial_rate_std: float = 0.05
    min_std: float = 1.0
    noise_scale: float = 1.3
    outlier_sigma: float = 3.0
    window: int = 100
    rate_drifts: tuple[float, ...] = (1e-9, 1e-8, 1e-7, 1e-6, 1e-5, 1e-4, 1e-3, 1e-2, 1e-1)
    forgetting: float = 0.97
    horizons_days: tuple[float, ...] = (7.0, 30.0)
    learning_cycles: int = 30            # estimates the trend takes before it forecasts
    after_alarm: bool = True             # forecast only while a detector of the joint has an alarm latched
    trend_sigma: float = 1.0             # the rate must be this many of its std above 0 to be a trend
    warning_probability: float = 0.0     # early warning when P(critical within warning_horizon_days) ≥ this (0: off)
    warning_horizon_days: float = 7.0
    wear_input: str = "estimate"         # what the trend is fed each cycle: a key of WEAR_INPUTS

    def __post_init__(self) -> None:
        TrendConfig(**self._trend_fields())              # validates the model's settings
        require(self.wear_input in WEAR_INPUTS, "prognosis.wear_input",
                f"must be one of {', '.join(WEAR_INPUTS)}, got {self.wear_input!r}")
        require(isinstance(self.horizons_days, tuple) and 1 <= len(self.horizons_days) <= 8
                and all(is_finite_number(h) and 0 < h <= 3650 for h in self.horizons_days)
                and len(set(self.horizons_days)) == len(self.horizons_days),
                "prognosis.horizons_days",
                f"need 1 … 8 different horizons in (0, 3650] days, got {self.horizons_days!r}")
        require(isinstance(self.learning_cycles, int) and 3 <= self.learning_cycles <= 10_000,
                "prognosis.learning_cycles", f"must be 3 … 10000 cycles, got {self.learning_cycles!r}")
        require(math.isfinite(self.trend_sigma) and 0 <= self.trend_sigma <= 10, "prognosis.trend_sigma",
                f"must be 0 … 10, got {self.trend_sigma}")
        require(math.isfinite(self.warning_probability) and 0 <= self.warning_probability < 1,
                "prognosis.warning_probability",
                f"must be in [0, 1) (0: no early warning), got {self.warning_probability}")
        require(math.isfinite(self.warning_horizon_days) and 0 < self.warning_horizon_days <= 3650,
                "prognosis.warning_horizon_days", f"must be in (0, 3650] days, got {self.warning_horizon_days}")

    def _trend_fields(self) -> dict[str, Any]:
        return {f.name: getattr(self, f.name) for f in fields(TrendConfig)}

    @property
    def trend(self) -> TrendConfig:
        """The trend model's settings."""
        return TrendConfig(**self._trend_fields())

    @property
    def horizon_days(self) -> float:
        """The horizon "beyond the horizon" refers to: the longest one [days]."""
        return max(self.horizons_days)


def horizon_key(days: float) -> str:
    """The key of a horizon in ``p_critical``: ``"7"``, ``"0.5"``."""
    return f"{days:g}"


@dataclass(frozen=True)
class Forecast:
    """One cycle's prognosis. ``cycles``: (p10, median, p90) cycles until the critical wear, an entry
    ``None`` beyond the grid (or all None without a trend); ``p_within``: P(critical within each horizon
    in days); ``level``/``rate``: the trend's wear [wear] and rate [wear per cycle]."""

    state: str
    critical_wear: float
    cycles_per_day: float
    horizon_days: float
    level: float | None = None
    rate: float | None = None
    cycles: tuple[float | None, float | None, float | None] | None = None
    p_within: tuple[tuple[float, float | None], ...] = ()
    model: str = ""

    @property
    def beyond_horizon(self) -> bool:
        """No critical wear expected within the horizon: no trend, or the median beyond it."""
        if self.state == "critical":
            return False
        median = None if self.cycles is None else self.cycles[1]
        return self.state != "forecast" or median is None or median > self.horizon_days * self.cycles_per_day

    def section(self) -> dict[str, Any]:
        """The symptom's ``prognosis`` object (docs/OUTPUTS.md)."""
        published = self.state == "forecast" and not self.beyond_horizon and self.cycles is not None
        band = dict(zip(("p10", "median", "p90"), self.cycles)) if published and self.cycles else None
        rate = None if self.rate is None or self.state == "learning" else self.rate * self.cycles_per_day
        return {"model": self.model, "state": self.state, "critical_wear": self.critical_wear,
                "level": _round(self.level, 2), "wear_rate_per_day": _round(rate, 4),
                "cycles": None if band is None else {k: _round(v, 1) for k, v in band.items()},
                "days": None if band is None else {k: _round(None if v is None else v / self.cycles_per_day, 3)
                                                   for k, v in band.items()},
                "beyond_horizon": self.beyond_horizon, "horizon_days": self.horizon_days,
                "cycles_per_day": round(self.cycles_per_day, 2),
                "p_critical": {horizon_key(d): _round(p, 4) for d, p in self.p_within}, "text": self.text()}

    def text(self) -> str:
        """One line for a person: "critical wear 35 in about 12 days (8–20)"."""
        c = f"critical wear {self.critical_wear:g}"
        if self.state == "learning":
            return f"{c}: learning the wear trend"
        if self.state == "critical":
            return f"{c} reached (wear {self.level:.1f})"
        if self.beyond_horizon or self.cycles is None:
            why = "no growing wear found" if self.state == "no_trend" else "wear growing slowly"
            return f"{c}: {why}, beyond the {self.horizon_days:g}-day horizon"
        lo, mid, hi = (None if v is None else v / self.cycles_per_day for v in self.cycles)
        if mid is not None and mid < 1:                  # under a day: in test cycles, as the controller counts
            cycles = ["?" if v is None else f"{v:.0f}" for v in self.cycles]
            upper = f"{GRID_REACH * self.horizon_days * self.cycles_per_day:.0f}+" if hi is None else cycles[2]
            return f"{c} in about {cycles[1]} test cycles ({cycles[0]}–{upper}, 80 %; {_days(mid)} days)"
        upper = f"{GRID_REACH * self.horizon_days:.0f}+" if hi is None else _days(hi)   # past the grid
        return f"{c} in about {_days(mid)} days ({_days(lo)}–{upper}, 80 %)"


def _days(value: float | None) -> str:
    if value is None:
        return "?"
    return f"{value:.0f}" if value >= 10 else f"{value:.2g}"


def _round(value: float | None, digits: int) -> float | None:
    return None if value is None or not math.isfinite(value) else round(float(value), digits)


class JointPrognosis:
    """The prognosis of one joint (see the module docstring): ``update(...)`` → :class:`Forecast`."""

    def __init__(self, config: PrognosisConfig, critical_wear: float) -> None:
        self.config = config
        self.critical_wear = float(critical_wear)
        self.trend: WearTrend = new_trend(config.trend)
        self.warning = False              # the early warning is on
        self.below = 0                    # cycles in a row the warning's probability was below half its level

    def reset(self) -> None:
        """Declared maintenance: the gearbox is new, its wear history gone."""
        self.trend, self.warning, self.below = new_trend(self.config.trend), False, 0

    def update(self, cycle: int, estimate: float | None, std: float | None, *, use: bool, alarm: bool,
               cycles_per_day: float) -> Forecast:
        """Cycle ``cycle``'s wear estimate and std [wear] (``use`` False: published but not fed — the
        joint's model is learning or the cycle is partial), whether a detector of the joint has an alarm
        latched, and the test cycles a day [cycles/day] the days are counted at."""
        self.trend.update(cycle, estimate if use else None, std if use else None)
        c = self.config
        if self.trend.updates < c.learning_cycles:
            return self._forecast("learning", cycles_per_day, p_within=tuple((d, None) for d in c.horizons_days))
        level, rate = self.trend.level, self.trend.rate
        grid = horizon_grid(GRID_REACH * c.horizon_days * cycles_per_day)
        trending = (not c.after_alarm or alarm) and rate > 0 and self.trend.rate_z > c.trend_sigma
        if trending:
            cdf = self.trend.crossing_cdf(self.critical_wear, grid)
        else:                                  # the level alone: its own uncertainty, no growth
            cdf = np.full_like(grid, self.trend.crossing_cdf(self.critical_wear, grid[:1])[0])
        p_within = tuple((d, probability_within(grid, cdf, d * cycles_per_day)) for d in c.horizons_days)
        state = "critical" if level >= self.critical_wear else "forecast" if trending else "no_trend"
        band = quantiles(grid, cdf, BAND) if state == "forecast" else None
        return self._forecast(state, cycles_per_day, level=level, rate=rate, p_within=p_within,
                              cycles=None if band is None else (band[0], band[1], band[2]))

    def _forecast(self, state: str, cycles_per_day: float, **fields: Any) -> Forecast:
        return Forecast(state, self.critical_wear, float(cycles_per_day), self.config.horizon_days,
                        model=self.config.model, **fields)

    def warning_advisory(self, robot: str, joint: int, cycle: int, forecast: Forecast) -> Advisory | None:
        """The early warning's advisory record when it changes (:meth:`warning_change`), else None."""
        change = self.warning_change(forecast)
        if change is None:
            return None
        c = self.config
        return Advisory(robot, joint, cycle, "prognosis", change, f"p_critical_{c.warning_horizon_days:g}d",
                        self.warning_probability(forecast), (c.warning_probability, c.warning_horizon_days),
                        prognosis=forecast.section())

    def warning_change(self, forecast: Forecast) -> str | None:
        """"entered" when P(critical within the warning horizon) first reaches ``warning_probability``,
        "left" when it has stayed below half of it :data:`WARNING_CLEAR_CYCLES` cycles in a row; None
        otherwise (and always with the warning off)."""
        c = self.config
        if c.warning_probability <= 0 or forecast.state == "learning":
            return None
        p = self.warning_probability(forecast)
        self.below = self.below + 1 if p < c.warning_probability / 2 else 0
        if not self.warning and p >= c.warning_probability:
            self.warning = True
            return "entered"
        if self.warning and self.below >= WARNING_CLEAR_CYCLES:
            self.warning = False
            return "left"
        return None

    def warning_probability(self, forecast: Forecast) -> float:
        """P(critical within ``warning_horizon_days``) of ``forecast`` (from its horizons, or computed)."""
        for days, p in forecast.p_within:
            if days == self.config.warning_horizon_days:
                return 0.0 if p is None else p
        grid = horizon_grid(GRID_REACH * self.config.horizon_days * forecast.cycles_per_day)
        return probability_within(grid, self.trend.crossing_cdf(self.critical_wear, grid),
                                  self.config.warning_horizon_days * forecast.cycles_per_day) \
            if forecast.state in ("forecast", "critical") else 0.0

    def state_dict(self) -> dict[str, Any]:
        return {"trend": self.trend.state_dict(), "warning": self.warning, "below": self.below,
                "critical_wear": self.critical_wear}

    @classmethod
    def from_state(cls, config: PrognosisConfig, critical_wear: float, state: dict[str, Any]) -> "JointPrognosis":
        """Restore; StateMismatch (the trend's settings changed) or ValueError/KeyError/TypeError for a
        damaged state: the caller starts a fresh trend."""
        out = cls(config, critical_wear)
        out.trend = trend_from_state(config.trend, state["trend"])
        out.warning = state.get("warning") is True
        below = state.get("below", 0)
        out.below = below if isinstance(below, int) and not isinstance(below, bool) and 0 <= below < 2 ** 31 else 0
        return out


def config_dict(config: PrognosisConfig) -> dict[str, Any]:
    """The settings as a JSON-ready mapping (for the state queryable and summaries)."""
    return {k: list(v) if isinstance(v, tuple) else v for k, v in asdict(config).items()}
