"""Drawing blocks of records into a Rerun recording stream, one ``send_columns`` call per entity
(used by :class:`edge_monitor.sinks.rerun_view.RerunSink`; entity paths in docs/OUTPUTS.md)."""

from __future__ import annotations

from collections import deque
from typing import Any

import numpy as np
from numpy.typing import ArrayLike

from edge_monitor.sinks.rerun_blueprint import joint_path
from joint_model import CRITICAL_WEAR, WEAR_MAX

FRICTION_SCALE = 1000.0            # friction drawn in ‰ of the joint's maximum torque
DENSITY_HEIGHT = 100.0             # nominal density peak drawn at this height
#: Static transform of the 2D entities: Rerun's 2D y axis points down; this flips it so that the logged
#: values keep their sign (y = +torque ‰, +density) and up on screen is more.
Y_UP = (1.0, -1.0, 1.0)
_VIRIDIS = np.array([[68, 1, 84], [59, 82, 139], [33, 145, 140], [94, 201, 98], [253, 231, 37]], float)
#: The forecast cone's x axis: the prognosis horizon is drawn this wide (wear units on the y axis).
CONE_WIDTH = 60.0
#: Trend levels per joint the cone view draws behind "now" (the sink's only per-joint history).
CONE_HISTORY = 600
_QUANTITY_COLORS = {"wear": [230, 120, 30], "kl_raw": [90, 90, 220], "kl_weighted": [40, 170, 90],
                    "joint": [200, 40, 160]}


def cycle_colors(cycles: ArrayLike, span: int) -> np.ndarray:
    """RGB uint8 colours (viridis) for cycle numbers: cycle 0 dark blue → cycle ``span`` and later yellow."""
    x = np.clip(np.asarray(cycles, float) / max(span, 1), 0.0, 1.0) * (len(_VIRIDIS) - 1)
    anchors = np.arange(len(_VIRIDIS))
    rgb = np.stack([np.interp(x, anchors, _VIRIDIS[:, c]) for c in range(3)], axis=-1)
    return rgb.round().astype(np.uint8)


def wear_bounds(block: list[dict]) -> tuple[np.ndarray, np.ndarray]:
    """(upper, lower) wear bound per record: ϖ̂ ± 2σ clipped to 0 … WEAR_MAX where wear is identifiable
    (or the record does not say), else the one-sided 95 % bound: upper = ``upper_95``, lower = 0 (near
    ϖ = 0 the data cannot tell low wear from none and σ is meaningless; docs/WEAR_ESTIMATION.md)."""
    upper, lower = [], []
    for r in block:
        wear = r.get("wear")
        if not isinstance(wear, dict):
            wear = {}
        estimate, std, bound = _number(wear.get("estimate")), _number(wear.get("std")), _number(wear.get("upper_95"))
        if wear.get("identifiable") is False and np.isfinite(bound):
            upper.append(min(bound, WEAR_MAX))
            lower.append(0.0 if np.isfinite(estimate) else np.nan)
        else:
            upper.append(min(estimate + 2 * std, WEAR_MAX))
            lower.append(max(estimate - 2 * std, 0.0))
    return np.array(upper, float), np.array(lower, float)
#: Alarm states a person must act on (drawn as warnings; acknowledged and cleared ones as information).
ALERTING = ("raised", "updated", "chattering")


def alarm_text(record: dict) -> str:
    """One line of a joint's alarm log: the fault, what happened, and the evidence of the detectors named
    (``cycle 118: fault r1/2/118 raised — wear statistic 14.2 vs threshold 11.3, change at cycle 96, …``)."""
    state = record.get("state", "raised")
    detectors = record.get("detectors")
    if not isinstance(detectors, list) or not detectors:       # a record of one detector (older agents)
        detectors = [record]
    evidence = "; ".join(
        f"{d.get('quantity')} statistic {_number(d.get('statistic')):.4g} vs threshold "
        f"{_number(d.get('threshold')):.4g}, change at cycle {d.get('change_cycle')}, miss probability "
        f"{_number(d.get('miss_probability')):.3g}" if state in ALERTING else str(d.get("quantity"))
        for d in detectors if isinstance(d, dict))
    what = f"fault {record['fault']}" if record.get("fault") else f"{record.get('quantity')} alarm"
    return f"cycle {record.get('cycle')}: {what} {state} — {evidence}"


def _number(value: Any) -> float:
    """float(value), NaN for None / non-numbers."""
    try:
        return float(value) if value is not None else float("nan")
    except (TypeError, ValueError):
        return float("nan")


def _array(value: Any) -> np.ndarray:
    """A 1-d float array of a list or array (empty for None or what is not numeric)."""
    try:
        return np.asarray([] if value is None else value, dtype=float).ravel()
    except (TypeError, ValueError):
        return np.empty(0)

class Drawer:
    """Draws blocks of one recording stream ``rec``; remembers what static data it has logged and the
    nominal density it last drew per joint. Raises on failure (the sink counts it)."""

    def __init__(self, rec: Any, cycle_span: int = 1000) -> None:
        self.rec = rec
        self.cycle_span = cycle_span        # cycles over which friction colours run through viridis
        self._static: set[str] = set()      # entities whose static data is logged
        self._nominal: dict[str, np.ndarray] = {}   # joint path -> nominal density last drawn
        self._levels: dict[str, deque[tuple[int, float]]] = {}   # joint path -> recent (cycle, trend level)

    @staticmethod
    def _indexes(cycles: np.ndarray, times: np.ndarray) -> list[Any]:
        import rerun as rr

        indexes = [rr.TimeColumn("cycle", sequence=cycles)]
        if len(times) and np.isfinite(times).all():
            indexes.append(rr.TimeColumn("controller_time", duration=times))
        return indexes

    def _scalars(self, path: str, cycles: np.ndarray, times: np.ndarray, values: np.ndarray) -> None:
        import rerun as rr

        keep = np.isfinite(values)
        if not keep.any():
            return
        self.rec.send_columns(path, indexes=self._indexes(cycles[keep], times[keep]),
                              columns=rr.Scalars.columns(scalars=values[keep]))

    def _log_static_once(self, path: str, *archetypes: Any) -> None:
        if path in self._static:
            return
        self.rec.log(path, *archetypes, static=True)
        self._static.add(path)            # only once it was logged: a failure is retried next block

    def _style(self, path: str, name: str, color: list[int], width: float = 2.0) -> None:
        import rerun as rr

        self._log_static_once(path, rr.SeriesLines(colors=[color], names=[name], widths=[width]))

    def symptoms(self, robot: str, joint: int, block: list[dict]) -> None:
        base = joint_path(robot, joint)
        cycles = np.array([int(r["cycle"]) for r in block], dtype=np.int64)
        times = np.array([_number(r.get("t")) for r in block])

        def column(*keys: str) -> np.ndarray:
            out = []
            for r in block:
                value: Any = r
                for key in keys:
                    value = value.get(key) if isinstance(value, dict) else None
                out.append(_number(value))
            return np.array(out)

        upper, lower = wear_bounds(block)
        series = {
            "wear/estimate": (column("wear", "estimate"), "wear estimate", [230, 120, 30], 2.5),
            "wear/upper": (upper, "upper bound (+2σ, or 95 % one-sided)", [240, 180, 120], 1.0),
            "wear/lower": (lower, "lower bound (−2σ, or 0)", [240, 180, 120], 1.0),
            "wear/trend": (column("prognosis", "level"), "wear trend (prognosis)", [120, 60, 10], 2.0),
            "prognosis/days/median": (column("prognosis", "days", "median"), "days to critical: median",
                                      [200, 40, 40], 2.5),
            "prognosis/days/p10": (column("prognosis", "days", "p10"), "10 %", [230, 140, 140], 1.0),
            "prognosis/days/p90": (column("prognosis", "days", "p90"), "90 %", [230, 140, 140], 1.0),
            "temperature": (column("wear", "temperature"), "lubricant temperature °C", [200, 80, 60], 1.5),
            "temperature/compensation": (column("kl", "temperature", "value"), "KL compensation's temperature °C",
                                         [120, 30, 20], 2.5),
            "kl/raw": (column("kl", "raw"), "KL raw", [90, 90, 220], 2.0),
            "kl/weighted": (column("kl", "weighted"), "KL weighted", [40, 170, 90], 2.0),
        }
        quantities = sorted({q for r in block for q in (r.get("decisions") or {})})
        for q in quantities:
            color = _QUANTITY_COLORS.get(q, [120, 120, 120])
            series[f"glr/{q}/statistic"] = (column("decisions", q, "statistic"), f"{q} GLR", color, 2.0)
            series[f"glr/{q}/threshold"] = (column("decisions", q, "threshold"), f"{q} threshold",
                                            [c // 2 for c in color], 1.0)
            series[f"miss/{q}"] = (column("decisions", q, "miss_probability"), f"{q} miss probability", color, 2.0)
            series[f"coverage/{q}"] = (column("coverage", q, "recent"), f"{q} tested (last 300 cycles)", color, 2.0)
        for sub, (values, name, color, width) in series.items():
            if np.isfinite(values).any():
                self._style(f"{base}/{sub}", name, color, width)
                self._scalars(f"{base}/{sub}", cycles, times, values)
        self._draw_critical(base, block, cycles, times)
        self._draw_cone(base, block, cycles, times)
        self._draw_friction(base, block, cycles, times)
        self._draw_density(base, block, cycles, times)

    def _draw_critical(self, base: str, block: list[dict], cycles: np.ndarray, times: np.ndarray) -> None:
        """The critical level: a constant, so two rows per block (its first and last cycle) draw the
        line; a time-series view does not plot static scalars. Its name is static."""
        critical = np.array([_number(r.get("critical_wear", CRITICAL_WEAR)) for r in block])
        if not np.isfinite(critical).any():
            return
        level = float(critical[np.isfinite(critical)][-1])
        self._style(f"{base}/wear/critical", f"critical level {level:g}", [220, 30, 30], 1.5)
        ends = np.unique([0, len(block) - 1])
        self._scalars(f"{base}/wear/critical", cycles[ends], times[ends], np.full(len(ends), level))

    def _draw_cone(self, base: str, block: list[dict], cycles: np.ndarray, times: np.ndarray) -> None:
        """The forecast cone as of the block's last cycle, in a 2D view: x = days from now (the prognosis
        horizon drawn :data:`CONE_WIDTH` wide), y = wear; the trend behind (its last :data:`CONE_HISTORY`
        levels), lines from the level now to the critical level at the 10 %, median and 90 % days, the
        critical level and the horizon."""
        import rerun as rr

        history = self._levels.setdefault(base, deque(maxlen=CONE_HISTORY))
        history.extend((int(r["cycle"]), _number((r.get("prognosis") or {}).get("level"))) for r in block)
        last = block[-1].get("prognosis")
        if not isinstance(last, dict) or not np.isfinite(_number(last.get("level"))):
            return
        rate, horizon = _number(last.get("cycles_per_day")), _number(last.get("horizon_days"))
        critical, level = _number(last.get("critical_wear")), _number(last.get("level"))
        if not (rate > 0 and horizon > 0 and np.isfinite(critical)):
            return
        scale = CONE_WIDTH / horizon                                    # x units per day
        past = np.array([((c - int(cycles[-1])) / rate * scale, w) for c, w in history if np.isfinite(w)])
        left = min(float(past[:, 0].min()) if past.size else 0.0, -CONE_WIDTH / 4)
        strips = [past, np.array([[left, critical], [CONE_WIDTH * 1.2, critical]]),
                  np.array([[CONE_WIDTH, 0.0], [CONE_WIDTH, critical]])]
        colors, labels = [[120, 60, 10], [220, 30, 30], [150, 150, 150]], ["trend", f"critical {critical:g}",
                                                                             f"horizon {horizon:g} d"]
        days = last.get("days")
        days = days if isinstance(days, dict) else {}
        for key, color in (("p10", [230, 140, 140]), ("median", [200, 40, 40]), ("p90", [230, 140, 140])):
            value = _number(days.get(key))
            if np.isfinite(value):
                strips.append(np.array([[0.0, level], [value * scale, critical]]))
                colors.append(color)
                labels.append(f"{key} {value:.3g} d")
        path = f"{base}/prognosis/cone"
        self._log_static_once(path, rr.Transform3D(scale=Y_UP))
        self.rec.send_columns(path, indexes=self._indexes(cycles[-1:], times[-1:]),
                              columns=rr.LineStrips2D.columns(strips=strips, colors=colors, labels=labels,
                                                              radii=np.full(len(strips), 0.4, np.float32)
                                                              ).partition([len(strips)]))

    def _draw_friction(self, base: str, block: list[dict], cycles: np.ndarray, times: np.ndarray) -> None:
        import rerun as rr

        positions, lengths = [], []
        for r in block:
            friction = r.get("friction") or {}
            speeds = np.array([_number(v) for v in friction.get("speeds") or []])
            torque = np.array([_number(v) for v in friction.get("torque") or []])
            n = min(len(speeds), len(torque))
            xy = np.stack([speeds[:n], FRICTION_SCALE * torque[:n]], axis=-1)   # y = +torque ‰ (Y_UP flips)
            xy = xy[np.isfinite(xy).all(axis=1)]
            positions.append(xy)
            lengths.append(len(xy))
        if not sum(lengths):
            return
        path = f"{base}/friction/curve"
        self._log_static_once(path, rr.Transform3D(scale=Y_UP))
        colors = np.concatenate([np.repeat(cycle_colors([c], self.cycle_span), n, axis=0)
                                 for c, n in zip(cycles, lengths)])
        columns = rr.Points2D.columns(positions=np.concatenate(positions), colors=colors,
                                      radii=np.full(sum(lengths), 1.5, np.float32)).partition(lengths)
        self.rec.send_columns(path, indexes=self._indexes(cycles, times), columns=columns)

    def _draw_density(self, base: str, block: list[dict], cycles: np.ndarray, times: np.ndarray) -> None:
        """The torque density of every cycle of the block (x = torque ‰, y scaled so that the nominal
        peak is DENSITY_HEIGHT) and the nominal density when it changed (it is learned once)."""
        import rerun as rr

        rows: dict[str, list[tuple[int, np.ndarray]]] = {"cycle": [], "nominal": []}
        for i, record in enumerate(block):
            density = record.get("density")
            if not isinstance(density, dict):
                continue
            grid = _array(density.get("grid")) * FRICTION_SCALE     # lists from JSON, arrays in-process
            nominal, cycle = _array(density.get("nominal")), _array(density.get("cycle"))
            if not grid.size:
                continue
            # scaled so that the nominal peak is DENSITY_HEIGHT (before the nominal is learned: the cycle's peak)
            reference = nominal if nominal.size and np.nanmax(nominal) > 0 else cycle
            peak = np.nanmax(reference) if reference.size and np.nanmax(reference) > 0 else 1.0
            if cycle.size == grid.size:
                rows["cycle"].append((i, np.stack([grid, DENSITY_HEIGHT * cycle / peak], axis=-1)))
            if nominal.size == grid.size:
                last = self._nominal.get(base)
                if last is None or last.shape != nominal.shape or not np.array_equal(last, nominal):
                    self._nominal[base] = nominal.copy()
                    rows["nominal"].append((i, np.stack([grid, DENSITY_HEIGHT * nominal / peak], axis=-1)))
        for name, color in (("nominal", [150, 150, 150]), ("cycle", [230, 120, 30])):
            if not rows[name]:
                continue
            path = f"{base}/density/{name}"
            self._log_static_once(path, rr.Transform3D(scale=Y_UP))
            at = np.array([i for i, _ in rows[name]])
            n = len(at)
            columns = rr.LineStrips2D.columns(strips=[strip for _, strip in rows[name]], colors=[color] * n,
                                              radii=np.full(n, 0.5, np.float32), labels=[name] * n
                                              ).partition([1] * n)
            self.rec.send_columns(path, indexes=self._indexes(cycles[at], times[at]), columns=columns)

    def alarms(self, robot: str, joint: int, block: list[dict]) -> None:
        import rerun as rr

        block.sort(key=lambda r: int(r["cycle"]))
        texts, levels = [], []
        for record in block:
            state = record.get("state", "raised")
            texts.append(alarm_text(record))
            levels.append(rr.TextLogLevel.WARN if state in ALERTING else rr.TextLogLevel.INFO)
        cycles = np.array([int(r["cycle"]) for r in block], dtype=np.int64)
        times = np.array([_number(r.get("t")) for r in block])
        self.rec.send_columns(f"{joint_path(robot, joint)}/alarms", indexes=self._indexes(cycles, times),
                              columns=rr.TextLog.columns(text=texts, level=levels))

    def advisories(self, robot: str, joint: int, block: list[dict]) -> None:
        """Advisories (not faults) as their own text log of the joint, apart from its alarms."""
        import rerun as rr

        block.sort(key=lambda r: int(r["cycle"]))
        texts = [f"cycle {r.get('cycle')}: {r.get('message') or r.get('advisory')}" for r in block]
        cycles = np.array([int(r["cycle"]) for r in block], dtype=np.int64)
        times = np.array([_number(r.get("t")) for r in block])
        self.rec.send_columns(f"{joint_path(robot, joint)}/advisories", indexes=self._indexes(cycles, times),
                              columns=rr.TextLog.columns(text=texts, level=[rr.TextLogLevel.INFO] * len(texts)))

    def health(self, robot: str, rows: list[tuple[float, dict[str, float]]]) -> None:
        import rerun as rr

        stamps = np.array([stamp for stamp, _ in rows])
        for name in sorted({name for _, numbers in rows for name in numbers}):
            values = np.array([numbers.get(name, np.nan) for _, numbers in rows])
            keep = np.isfinite(values)
            self.rec.send_columns(f"/robot/{robot}/agent/health/{name}",
                                  indexes=[rr.TimeColumn("wall_time", timestamp=stamps[keep])],
                                  columns=rr.Scalars.columns(scalars=values[keep]))

