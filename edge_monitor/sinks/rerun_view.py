"""Live Rerun view of symptom records: one explicit recording stream, a default blueprint per joint.

Sinks (``--rerun SPEC``): ``off`` | ``save:PATH`` | ``spawn`` | ``connect[:URL]``. ``rerun`` is imported
only when the sink is not ``off``, so the agent runs without it. Entity paths (see docs/OUTPUTS.md)::

    /robot/<r>/joint/<j>/wear/{estimate,upper,lower,critical}    wear ϖ̂, ϖ̂ ± 2σ, critical level
    /robot/<r>/joint/<j>/temperature                              estimated lubricant temperature, °C
    /robot/<r>/joint/<j>/kl/{raw,weighted}                        symmetric KL distance to nominal
    /robot/<r>/joint/<j>/glr/<quantity>/{statistic,threshold}     GLR decision statistic vs threshold
    /robot/<r>/joint/<j>/miss/<quantity>                          estimated miss probability
    /robot/<r>/joint/<j>/friction/curve                           friction points of every cycle (2D)
    /robot/<r>/joint/<j>/density/{nominal,cycle}                  torque density curves (2D)
    /robot/<r>/joint/<j>/alarms                                   alarm text log
    /robot/<r>/agent/health/<counter>                             agent health counters and rates

Timelines: ``cycle`` (sequence) and ``controller_time`` (duration, s) for symptoms; ``wall_time``
(timestamp) for health. Logging never raises: failures are logged once and counted in ``errors``.
"""

from __future__ import annotations

import logging
import os
import shutil
import subprocess
import sys
import time
from collections import defaultdict
from pathlib import Path
from typing import Any, Iterable

import numpy as np
from numpy.typing import ArrayLike

from edge_monitor.records import Alarm, Health, Symptom
from edge_monitor.sinks.loopback import free_loopback_port
from edge_monitor.sinks.rerun_blueprint import fleet_blueprint, joint_path
from joint_model import CRITICAL_WEAR, WEAR_MAX

log = logging.getLogger(__name__)

APP_ID = "joint-wear-monitor"
FRICTION_SCALE = 1000.0            # friction drawn in ‰ of the joint's maximum torque
DENSITY_HEIGHT = 100.0             # nominal density peak drawn at this height
DEFAULT_VIEWER_PORT = 9876
_VIRIDIS = np.array([[68, 1, 84], [59, 82, 139], [33, 145, 140], [94, 201, 98], [253, 231, 37]], float)
_QUANTITY_COLORS = {"wear": [230, 120, 30], "kl_raw": [90, 90, 220], "kl_weighted": [40, 170, 90],
                    "joint": [200, 40, 160]}


class RerunSetupError(ValueError):
    """A Rerun sink could not be opened (bad spec, unwritable path)."""


def cycle_colors(cycles: ArrayLike, span: int) -> np.ndarray:
    """RGB uint8 colours (viridis) for cycle numbers: cycle 0 dark blue → cycle ``span`` and later yellow."""
    x = np.clip(np.asarray(cycles, float) / max(span, 1), 0.0, 1.0) * (len(_VIRIDIS) - 1)
    anchors = np.arange(len(_VIRIDIS))
    rgb = np.stack([np.interp(x, anchors, _VIRIDIS[:, c]) for c in range(3)], axis=-1)
    return rgb.round().astype(np.uint8)


def _display_available() -> bool:
    if sys.platform != "linux":
        return True
    return bool(os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY"))


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


class RerunSink:
    """Draws symptom, alarm and health records into one Rerun recording (or nowhere, for ``off``).

    Not thread-safe: call it from one thread (the agent's output thread, the view's draw loop).
    """

    def __init__(self, rec: Any, spec: str, cycle_span: int = 1000) -> None:
        self.rec = rec
        self.spec = spec                    # effective sink after any fallback
        self.cycle_span = cycle_span        # cycles over which friction colours run through viridis
        self.fallback_reason: str | None = None
        self.records_logged = 0
        self.alarms_logged = 0
        self.health_logged = 0
        self.errors = 0
        self._failed: set[str] = set()
        self._styled: set[str] = set()
        self._layout: dict[str, set[int]] = defaultdict(set)   # robot -> joints drawn
        self._health_robots: set[str] = set()
        self._viewer: subprocess.Popen | None = None

    # -- opening -----------------------------------------------------------------------------------

    @classmethod
    def open(cls, spec: str, app_id: str = APP_ID, recording_id: str | None = None,
             fallback_save: str | None = None) -> "RerunSink":
        """Open the sink named by ``spec``; ``spawn`` without a display falls back to
        ``save:<fallback_save>`` (or ``off``) with a warning. Raises :class:`RerunSetupError`."""
        kind, _, arg = spec.partition(":")
        if kind == "off":
            return cls(None, "off")
        if kind not in ("save", "spawn", "connect"):
            raise RerunSetupError(f"--rerun {spec!r}: use off, save:PATH, spawn or connect:URL")
        if kind == "save" and not arg:
            raise RerunSetupError("--rerun save: needs a path, e.g. save:run.rrd")
        if kind == "spawn" and not _display_available():
            reason = "no display (DISPLAY/WAYLAND_DISPLAY unset): cannot spawn the Rerun viewer"
            fallback = f"save:{fallback_save}" if fallback_save else "off"
            log.warning("%s; recording goes to %s instead", reason, fallback)
            sink = cls.open(fallback, app_id, recording_id)
            sink.fallback_reason = reason
            return sink
        import rerun as rr  # lazy: the wheel is large and only needed when drawing

        rec = rr.RecordingStream(app_id, recording_id=recording_id)
        sink = cls(rec, spec)
        try:
            if kind == "save":
                Path(arg).parent.mkdir(parents=True, exist_ok=True)
                rec.save(arg)
            elif kind == "spawn":
                sink._spawn_viewer()
            else:
                rec.connect_grpc(_grpc_url(arg))
        except (OSError, RuntimeError) as exc:
            raise RerunSetupError(f"--rerun {spec!r} failed: {exc}; choose a writable path or reachable "
                                  "viewer, or use --rerun off") from exc
        return sink

    def _spawn_viewer(self) -> None:
        """Start a native viewer whose gRPC server binds 127.0.0.1 only, then connect to it."""
        executable = shutil.which("rerun", path=str(Path(sys.executable).parent)) or shutil.which("rerun")
        if executable is None:
            raise RuntimeError("the rerun executable is not installed")
        port = free_loopback_port(DEFAULT_VIEWER_PORT)
        self._viewer = subprocess.Popen(
            [executable, "--bind", "127.0.0.1", "--port", str(port), "--memory-limit", "25%"],
            stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
            start_new_session=True)
        self.rec.connect_grpc(f"rerun+http://127.0.0.1:{port}/proxy")

    @property
    def enabled(self) -> bool:
        return self.rec is not None

    # -- public logging API ------------------------------------------------------------------------

    def log_symptom(self, record: dict) -> None:
        """Draw one per-cycle symptom record."""
        self.log_symptoms([record])

    def log_symptoms(self, records: Iterable[dict]) -> None:
        """Draw a block of symptom records (any robots/joints), column-wise with ``send_columns``."""
        if self.rec is None:
            return
        groups: dict[tuple[str, int], list[dict]] = defaultdict(list)
        for record in records:
            try:
                groups[(str(record["robot"]), int(record["joint"]))].append(record)
            except (KeyError, TypeError, ValueError) as exc:
                self._fail("symptom", ValueError(f"record without robot/joint: {exc}"))
        new_joints = [(robot, joint) for robot, joint in groups if joint not in self._layout[robot]]
        if new_joints:   # one blueprint for every joint that appears in this block
            for robot, joint in new_joints:
                self._layout[robot].add(joint)
            self._send_blueprint()
        for (robot, joint), block in groups.items():
            try:
                block.sort(key=lambda r: int(r["cycle"]))
                self._draw_block(robot, joint, block)
                self.records_logged += len(block)
            except Exception as exc:  # drawing must never take the agent down
                self._fail("symptom", exc)

    def log_alarm(self, record: dict) -> None:
        """Draw an alarm raised/cleared record as a text-log entry of its joint."""
        if self.rec is None:
            return
        try:
            import rerun as rr

            robot, joint = str(record["robot"]), int(record["joint"])
            self._ensure_layout(robot, joint)
            raised = record.get("state", "raised") == "raised"
            text = (f"cycle {record.get('cycle')}: {record.get('quantity')} alarm {record.get('state', 'raised')}"
                    f" — statistic {_number(record.get('statistic')):.4g} vs threshold "
                    f"{_number(record.get('threshold')):.4g}, change at cycle {record.get('change_cycle')}, "
                    f"miss probability {_number(record.get('miss_probability')):.3g}")
            indexes = [rr.TimeColumn("cycle", sequence=[int(record["cycle"])])]
            if record.get("t") is not None:
                indexes.append(rr.TimeColumn("controller_time", duration=[float(record["t"])]))
            level = rr.TextLogLevel.WARN if raised else rr.TextLogLevel.INFO
            self.rec.send_columns(f"{joint_path(robot, joint)}/alarms", indexes=indexes,
                                  columns=rr.TextLog.columns(text=[text], level=[level]))
            self.alarms_logged += 1
        except Exception as exc:
            self._fail("alarm", exc)

    def log_health(self, record: dict, robot: str | None = None) -> None:
        """Draw the numeric fields of an agent health record on the ``wall_time`` timeline."""
        if self.rec is None:
            return
        try:
            import rerun as rr

            robot = str(robot or record.get("robot", "unknown"))
            if robot not in self._health_robots:
                self._health_robots.add(robot)
                self._send_blueprint()
            stamp = float(record.get("time", time.time()))
            for name, value in record.items():
                if isinstance(value, bool) or not isinstance(value, (int, float)) or name == "time":
                    continue
                if not np.isfinite(value):
                    continue
                self.rec.send_columns(f"/robot/{robot}/agent/health/{name}",
                                      indexes=[rr.TimeColumn("wall_time", timestamp=[stamp])],
                                      columns=rr.Scalars.columns(scalars=[float(value)]))
            self.health_logged += 1
        except Exception as exc:
            self._fail("health", exc)

    def flush(self) -> None:
        if self.rec is not None:
            try:
                self.rec.flush()
            except Exception as exc:
                self._fail("flush", exc)

    def close(self) -> None:
        """Flush and close the sink (the spawned viewer keeps running for the user)."""
        if self.rec is None:
            return
        self.flush()
        try:
            self.rec.disconnect()
        except Exception as exc:
            self._fail("close", exc)
        self.rec = None

    def stats(self) -> dict[str, Any]:
        return {"sink": self.spec, "records": self.records_logged, "alarms": self.alarms_logged,
                "health": self.health_logged, "errors": self.errors, "fallback": self.fallback_reason}

    # -- drawing -----------------------------------------------------------------------------------

    def _fail(self, what: str, exc: Exception) -> None:
        self.errors += 1
        if what not in self._failed:
            self._failed.add(what)
            log.warning("rerun: drawing %s failed (further failures only counted): %s", what, exc)

    def _scalars(self, path: str, cycles: np.ndarray, times: np.ndarray, values: np.ndarray) -> None:
        import rerun as rr

        keep = np.isfinite(values)
        if not keep.any():
            return
        indexes = [rr.TimeColumn("cycle", sequence=cycles[keep])]
        if np.isfinite(times[keep]).all():
            indexes.append(rr.TimeColumn("controller_time", duration=times[keep]))
        self.rec.send_columns(path, indexes=indexes, columns=rr.Scalars.columns(scalars=values[keep]))

    def _style(self, path: str, name: str, color: list[int], width: float = 2.0, points: bool = False) -> None:
        if path in self._styled:
            return
        import rerun as rr

        self._styled.add(path)
        style = (rr.SeriesPoints(colors=[color], names=[name], marker_sizes=[3.0]) if points
                 else rr.SeriesLines(colors=[color], names=[name], widths=[width]))
        self.rec.log(path, style, static=True)

    def _draw_block(self, robot: str, joint: int, block: list[dict]) -> None:
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

        wear, std = column("wear", "estimate"), column("wear", "std")
        critical = np.array([_number(r.get("critical_wear", CRITICAL_WEAR)) for r in block])
        series = {
            "wear/estimate": (wear, "wear estimate", [230, 120, 30], 2.5),
            # the band is clipped to the physical wear range 0 … 100: near ϖ = 0 the Cramér–Rao std is
            # huge (the wear term is not identifiable there) and an unclipped band hides the plot
            "wear/upper": (np.minimum(wear + 2 * std, WEAR_MAX), "+2σ", [240, 180, 120], 1.0),
            "wear/lower": (np.maximum(wear - 2 * std, 0.0), "−2σ", [240, 180, 120], 1.0),
            "wear/critical": (critical, "critical level", [220, 30, 30], 1.5),
            "temperature": (column("wear", "temperature"), "lubricant temperature °C", [200, 80, 60], 1.5),
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
        for sub, (values, name, color, width) in series.items():
            if np.isfinite(values).any():
                self._style(f"{base}/{sub}", name, color, width)
                self._scalars(f"{base}/{sub}", cycles, times, values)
        self._draw_friction(base, block, cycles, times)
        self._draw_density(base, block[-1])

    def _draw_friction(self, base: str, block: list[dict], cycles: np.ndarray, times: np.ndarray) -> None:
        import rerun as rr

        positions, lengths = [], []
        for r in block:
            friction = r.get("friction") or {}
            speeds = np.array([_number(v) for v in friction.get("speeds") or []])
            torque = np.array([_number(v) for v in friction.get("torque") or []])
            n = min(len(speeds), len(torque))
            xy = np.stack([speeds[:n], -FRICTION_SCALE * torque[:n]], axis=-1)   # 2D view: y points down
            xy = xy[np.isfinite(xy).all(axis=1)]
            positions.append(xy)
            lengths.append(len(xy))
        if not sum(lengths):
            return
        colors = np.concatenate([np.repeat(cycle_colors([c], self.cycle_span), n, axis=0)
                                 for c, n in zip(cycles, lengths)])
        indexes = [rr.TimeColumn("cycle", sequence=cycles)]
        if np.isfinite(times).all():
            indexes.append(rr.TimeColumn("controller_time", duration=times))
        columns = rr.Points2D.columns(positions=np.concatenate(positions), colors=colors,
                                      radii=np.full(sum(lengths), 1.5, np.float32)).partition(lengths)
        self.rec.send_columns(f"{base}/friction/curve", indexes=indexes, columns=columns)

    def _draw_density(self, base: str, record: dict) -> None:
        density = record.get("density")
        if not isinstance(density, dict):
            return
        grid = _array(density.get("grid")) * FRICTION_SCALE     # lists from JSON, arrays in-process
        if not grid.size:
            return
        import rerun as rr

        nominal = _array(density.get("nominal"))
        peak = np.nanmax(nominal) if nominal.size and np.nanmax(nominal) > 0 else 1.0
        self.rec.set_time("cycle", sequence=int(record["cycle"]))
        if record.get("t") is not None:
            self.rec.set_time("controller_time", duration=float(record["t"]))
        for name, color in (("nominal", [150, 150, 150]), ("cycle", [230, 120, 30])):
            values = _array(density.get(name))
            if values.size != grid.size:
                continue
            strip = np.stack([grid, -DENSITY_HEIGHT * values / peak], axis=-1)
            self.rec.log(f"{base}/density/{name}",
                         rr.LineStrips2D([strip], colors=[color], radii=[0.5], labels=[name]))

    # -- blueprint ---------------------------------------------------------------------------------

    def _ensure_layout(self, robot: str, joint: int) -> None:
        if joint not in self._layout[robot]:
            self._layout[robot].add(joint)
            self._send_blueprint()

    def _send_blueprint(self) -> None:
        try:
            self.rec.send_blueprint(fleet_blueprint(self._layout, self._health_robots), make_active=True,
                                    make_default=True)
        except Exception as exc:
            self._fail("blueprint", exc)


class RerunViewSink:
    """Sink adapter: draws each symptom (with the cycle's torque density over the nominal one), alarm
    and health record."""

    def __init__(self, rerun_sink: RerunSink) -> None:
        self.rerun = rerun_sink

    def on_symptom(self, symptom: Symptom) -> None:
        record = symptom.to_dict()
        density = symptom.extras.get("density")
        if density:
            record["density"] = density
        self.rerun.log_symptom(record)

    def on_alarm(self, alarm: Alarm) -> None:
        self.rerun.log_alarm(alarm.to_dict())

    def on_health(self, health: Health) -> None:
        self.rerun.log_health(health.numbers(), robot=health.robot)

    def close(self) -> None:
        self.rerun.close()


def _grpc_url(arg: str) -> str:
    """``connect:`` argument → gRPC proxy URL (default: the local viewer on 127.0.0.1:9876)."""
    if not arg:
        return f"rerun+http://127.0.0.1:{DEFAULT_VIEWER_PORT}/proxy"
    if "://" not in arg:
        return f"rerun+http://{arg}/proxy"
    return arg
