"""Rerun view of symptom records: one explicit recording stream, one default blueprint, column-wise blocks.

Sinks (``--rerun SPEC``): ``off`` | ``save:PATH`` | ``spawn`` | ``connect[:URL]``. ``rerun`` is imported
only when the sink is not ``off``, so the agent runs without it. Entity paths (see docs/OUTPUTS.md)::

    /robot/<r>/joint/<j>/wear/{estimate,upper,lower,critical}    wear ϖ̂, its bounds, critical level
    /robot/<r>/joint/<j>/temperature                              estimated lubricant temperature, °C
    /robot/<r>/joint/<j>/temperature/compensation                 the KL compensation's temperature, °C
    /robot/<r>/joint/<j>/kl/{raw,weighted}                        symmetric KL distance to nominal
    /robot/<r>/joint/<j>/glr/<quantity>/{statistic,threshold}     GLR decision statistic vs threshold
    /robot/<r>/joint/<j>/miss/<quantity>                          estimated miss probability
    /robot/<r>/joint/<j>/friction/curve                           friction points of every cycle (2D)
    /robot/<r>/joint/<j>/density/{nominal,cycle}                  torque density curves (2D)
    /robot/<r>/joint/<j>/alarms                                   alarm text log
    /robot/<r>/agent/health/<counter>                             agent health counters and rates

Timelines: ``cycle`` (sequence) and ``controller_time`` (duration, s) for symptoms; ``wall_time``
(timestamp) for health. Logging never raises: failures are logged once and counted in ``errors``.

Records are buffered and drawn in blocks (:class:`Batching`): a block is one ``send_columns`` call, so
one chunk, per entity. A recording file collects up to 4096 records or 10 minutes (a demo run is one
block: a compact file that ``rerun rrd stats`` does not call unoptimised); a live viewer gets what
arrived within a second, so the joints of one cycle come together. The blueprint is sent with the
first block and again only if a robot or joint appears later; series styles, 2D axis flips and the
critical-level name are static and logged once per entity.
"""

from __future__ import annotations

import logging
import os
import subprocess
import sys
import threading
import time
from collections import defaultdict
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable, Iterable

import numpy as np

from edge_monitor.records import Advisory, Alarm, Health, Symptom
from edge_monitor.sinks.loopback import free_loopback_port
from edge_monitor.sinks.rerun_blueprint import fleet_blueprint
from edge_monitor.sinks.rerun_cli import compact_recording, rerun_executable, usage_reporting_off
from edge_monitor.sinks.rerun_draw import DENSITY_HEIGHT, FRICTION_SCALE, Y_UP, Drawer, cycle_colors, wear_bounds
from joint_model import CRITICAL_WEAR

__all__ = ["APP_ID", "Batching", "CRITICAL_WEAR", "DENSITY_HEIGHT", "FRICTION_SCALE", "IMMEDIATE", "LIVE_BATCHING",
           "RerunSetupError", "RerunSink", "RerunViewSink", "SAVE_BATCHING", "Y_UP", "cycle_colors", "wear_bounds"]

log = logging.getLogger(__name__)

APP_ID = "joint-wear-monitor"
DEFAULT_VIEWER_PORT = 9876


@dataclass(frozen=True)
class Batching:
    """When buffered records are drawn: once ``records`` are pending, or ``seconds`` after the oldest
    pending one arrived (``None``: only by :meth:`RerunSink.flush` / :meth:`RerunSink.close`)."""

    records: int = 4096
    seconds: float | None = 600.0


#: A recording file: a block per 4096 records or 10 minutes (hours-long files: ``rerun rrd optimize``).
SAVE_BATCHING = Batching(records=4096, seconds=600.0)
#: A live viewer (``spawn``, ``connect``) and ``edge-monitor view``: what arrived within a second.
LIVE_BATCHING = Batching(records=4096, seconds=1.0)
#: Every record drawn at once (one chunk per record and entity).
IMMEDIATE = Batching(records=1, seconds=None)


class RerunSetupError(ValueError):
    """A Rerun sink spec that cannot work (``--rerun`` not off/save:PATH/spawn/connect:URL): a usage error."""


class RerunUnavailable(RerunSetupError):
    """A valid Rerun sink could not be opened (unwritable path, unreachable viewer): a runtime failure."""


def _display_available() -> bool:
    if sys.platform != "linux":
        return True
    return bool(os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY"))


class RerunSink:
    """Draws symptom, alarm and health records into one Rerun recording (or nowhere, for ``off``).

    Records are buffered and drawn in blocks as ``batching`` says (a daemon thread draws a block that
    has waited ``batching.seconds``); :meth:`flush` and :meth:`close` draw what is pending. Safe to call
    from several threads (one lock). ``records_logged``, ``alarms_logged`` and ``health_logged`` count
    what has been drawn, ``blueprints_sent`` the layouts sent.
    """

    def __init__(self, rec: Any, spec: str, cycle_span: int = 1000, batching: Batching = IMMEDIATE,
                 clock: Callable[[], float] = time.monotonic) -> None:
        self.rec = rec
        self.spec = spec                    # effective sink after any fallback
        self.batching = batching
        self.fallback_reason: str | None = None
        self.compact_on_close = False       # rewrite the closed file with its chunks compacted
        self.records_logged = 0
        self.alarms_logged = 0
        self.health_logged = 0
        self.blueprints_sent = 0
        self.errors = 0
        self._clock = clock
        self._lock = threading.RLock()
        self._pending: list[tuple[str, Any]] = []       # ("symptom" | "alarm" | "health", payload)
        self._pending_since: float | None = None
        self._failed: set[str] = set()
        self._layout: dict[str, set[int]] = defaultdict(set)   # robot -> joints drawn
        self._health_robots: set[str] = set()
        self._sent_layout: tuple[frozenset, frozenset] | None = None
        self.draw = Drawer(rec, cycle_span) if rec is not None else None
        self._viewer: subprocess.Popen | None = None
        self._stop = threading.Event()
        self._timer: threading.Thread | None = None
        if rec is not None and batching.seconds is not None:
            self._timer = threading.Thread(target=self._draw_when_due, name="rerun-blocks", daemon=True)
            self._timer.start()

    # -- opening -----------------------------------------------------------------------------------

    @classmethod
    def open(cls, spec: str, app_id: str = APP_ID, recording_id: str | None = None,
             fallback_save: str | None = None, batching: Batching | None = None,
             compact: bool | None = None) -> "RerunSink":
        """Open the sink named by ``spec``; ``spawn`` without a display falls back to
        ``save:<fallback_save>`` (or ``off``) with a warning. ``batching`` defaults to
        :data:`SAVE_BATCHING` for a file and :data:`LIVE_BATCHING` for a viewer. ``compact``: compact a
        saved file when it is closed (default: when it was drawn in smaller blocks than
        :data:`SAVE_BATCHING`'s, e.g. by ``view``). Raises :class:`RerunSetupError`."""
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
            sink = cls.open(fallback, app_id, recording_id, batching=batching, compact=compact)
            sink.fallback_reason = reason
            return sink
        usage_reporting_off()      # before the SDK loads or a viewer starts (docs/SECURITY.md)
        try:
            import rerun as rr  # lazy: the wheel is large and only needed when drawing
        except ImportError:
            raise RerunUnavailable(f"--rerun {spec!r} needs the Rerun viewer, which this installation has not: "
                                   "pip install 'joint-wear-monitor[viewer]', or --rerun off") from None

        rec = rr.RecordingStream(app_id, recording_id=recording_id)
        try:
            viewer = None
            if kind == "save":
                if not Path(arg).parent.is_dir():    # a typo in the path must not make a directory tree
                    raise OSError(f"its folder {Path(arg).parent} does not exist (create it, or fix the path)")
                rec.save(arg)
            elif kind == "spawn":
                viewer = _spawn_viewer(rec)
            else:
                rec.connect_grpc(_grpc_url(arg))
        except (OSError, RuntimeError) as exc:
            raise RerunUnavailable(f"--rerun {spec!r} failed: {exc}; choose a writable path or reachable "
                                  "viewer, or use --rerun off") from exc
        if batching is None:
            batching = SAVE_BATCHING if kind == "save" else LIVE_BATCHING
        sink = cls(rec, spec, batching=batching)
        sink.compact_on_close = kind == "save" and (batching != SAVE_BATCHING if compact is None else compact)
        sink._viewer = viewer
        return sink

    @property
    def enabled(self) -> bool:
        return self.rec is not None

    # -- public logging API ------------------------------------------------------------------------

    def log_symptom(self, record: dict) -> None:
        """Draw one per-cycle symptom record (with the next block)."""
        self.log_symptoms([record])

    def log_symptoms(self, records: Iterable[dict]) -> None:
        """Draw symptom records of any robots/joints, in any order (with the next block)."""
        if self.rec is None:
            return
        accepted = []
        for record in records:
            try:
                accepted.append((str(record["robot"]), int(record["joint"]), int(record["cycle"]), record))
            except (KeyError, TypeError, ValueError) as exc:
                self._fail("symptom", ValueError(f"record without robot/joint/cycle: {exc!r}"))
        self._enqueue([("symptom", item) for item in accepted])

    def log_alarm(self, record: dict, kind: str = "alarm") -> None:
        """Draw an alarm raised/cleared record (``kind="advisory"``: an advisory) as a text-log entry of
        its joint (with the next block)."""
        if self.rec is None:
            return
        try:
            item = (str(record["robot"]), int(record["joint"]), int(record["cycle"]), record)
        except (KeyError, TypeError, ValueError) as exc:
            self._fail(kind, ValueError(f"{kind} without robot/joint/cycle: {exc!r}"))
            return
        self._enqueue([(kind, item)])

    def log_health(self, record: dict, robot: str | None = None) -> None:
        """Draw the numeric fields of an agent health record on the ``wall_time`` timeline."""
        if self.rec is None:
            return
        try:
            robot = str(robot or record.get("robot", "unknown"))
            stamp = float(record.get("time", time.time()))
            numbers = {name: float(value) for name, value in record.items()
                       if not isinstance(value, bool) and isinstance(value, (int, float)) and name != "time"
                       and np.isfinite(value)}
        except Exception as exc:
            self._fail("health", exc)
            return
        self._enqueue([("health", (robot, stamp, numbers))])

    def flush(self) -> None:
        """Draw what is pending and flush the recording stream."""
        if self.rec is None:
            return
        with self._lock:
            self._draw_pending()
            try:
                self.rec.flush()
            except Exception as exc:
                self._fail("flush", exc)

    def close(self) -> None:
        """Draw what is pending, flush and close the sink (a spawned viewer keeps running for the user)."""
        if self.rec is None:
            return
        self._stop.set()
        if self._timer is not None:
            self._timer.join(timeout=10.0)
        with self._lock:
            self.flush()
            try:
                self.rec.disconnect()
            except Exception as exc:
                self._fail("close", exc)
            self.rec = None
        if self.compact_on_close:
            compact_recording(self.spec.partition(":")[2])

    def stats(self) -> dict[str, Any]:
        return {"sink": self.spec, "records": self.records_logged, "alarms": self.alarms_logged,
                "health": self.health_logged, "errors": self.errors, "fallback": self.fallback_reason,
                "blueprints": self.blueprints_sent}

    # -- blocks ------------------------------------------------------------------------------------

    def _enqueue(self, items: list[tuple[str, Any]]) -> None:
        if not items:
            return
        with self._lock:
            if self.rec is None:
                return
            if not self._pending:
                self._pending_since = self._clock()
            self._pending += items
            if len(self._pending) >= self.batching.records or self._due():
                self._draw_pending()

    def _due(self) -> bool:
        return (bool(self._pending) and self.batching.seconds is not None and self._pending_since is not None
                and self._clock() - self._pending_since >= self.batching.seconds)

    def _draw_when_due(self) -> None:
        assert self.batching.seconds is not None
        period = min(max(self.batching.seconds / 4, 0.05), 1.0)
        while not self._stop.wait(period):
            with self._lock:
                if self.rec is not None and self._due():
                    self._draw_pending()

    def _draw_pending(self) -> None:
        """Draw every pending record as one block: the blueprint first if the layout grew, then one
        ``send_columns`` per entity."""
        pending, self._pending, self._pending_since = self._pending, [], None
        if not pending or self.rec is None or self.draw is None:
            return
        draw = self.draw
        symptoms: dict[tuple[str, int], list[dict]] = defaultdict(list)
        alarms: dict[tuple[str, int], list[dict]] = defaultdict(list)
        advisories: dict[tuple[str, int], list[dict]] = defaultdict(list)
        health: dict[str, list[tuple[float, dict[str, float]]]] = defaultdict(list)
        for kind, item in pending:
            if kind == "health":
                robot, stamp, numbers = item
                health[robot].append((stamp, numbers))
                self._health_robots.add(robot)
            else:
                robot, joint, cycle, record = item
                {"symptom": symptoms, "advisory": advisories}.get(kind, alarms)[(robot, joint)].append(record)
                self._layout[robot].add(joint)
        layout = (frozenset((r, j) for r, js in self._layout.items() for j in js), frozenset(self._health_robots))
        if layout != self._sent_layout and (symptoms or alarms or self._stop.is_set()):
            self._send_blueprint()
            self._sent_layout = layout
        for (robot, joint), block in symptoms.items():
            block.sort(key=lambda r: int(r["cycle"]) if isinstance(r.get("cycle"), int) else -1)
            self.records_logged += self._draw_block(draw.symptoms, "symptom", robot, joint, block)
        for (robot, joint), block in alarms.items():
            self.alarms_logged += self._draw_block(draw.alarms, "alarm", robot, joint, block)
        for (robot, joint), block in advisories.items():
            self._draw_block(draw.advisories, "advisory", robot, joint, block)
        for robot, rows in health.items():
            try:
                draw.health(robot, rows)
                self.health_logged += len(rows)
            except Exception as exc:
                self._fail("health", exc)

    def _draw_block(self, draw: Any, kind: str, robot: str, joint: int, block: list[dict[str, Any]]) -> int:
        """Draw ``block`` at once; if that fails, record by record, so one bad record costs only itself
        (each failure counted). Returns how many records were drawn."""
        try:
            draw(robot, joint, block)
            return len(block)
        except Exception:  # noqa: BLE001 — isolate the bad record below; drawing never takes the agent down
            pass
        drawn = 0
        for record in block:
            try:
                draw(robot, joint, [record])
                drawn += 1
            except Exception as exc:  # noqa: BLE001
                self._fail(kind, exc)
        return drawn

    def _fail(self, what: str, exc: Exception) -> None:
        self.errors += 1
        if what not in self._failed:
            self._failed.add(what)
            log.warning("rerun: drawing %s failed (further failures only counted): %s", what, exc)

    def _send_blueprint(self) -> None:
        try:
            self.rec.send_blueprint(fleet_blueprint(self._layout, self._health_robots), make_active=True,
                                    make_default=True)
            self.blueprints_sent += 1
        except Exception as exc:
            self._fail("blueprint", exc)


def _spawn_viewer(rec: Any) -> subprocess.Popen:
    """Start a native viewer whose gRPC server binds 127.0.0.1 only, then connect ``rec`` to it."""
    executable = rerun_executable()
    if executable is None:
        raise RuntimeError("the rerun executable is not installed")
    port = free_loopback_port(DEFAULT_VIEWER_PORT)
    viewer = subprocess.Popen(
        [executable, "--bind", "127.0.0.1", "--port", str(port), "--memory-limit", "25%"],
        stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
        start_new_session=True)
    rec.connect_grpc(f"rerun+http://127.0.0.1:{port}/proxy")
    return viewer


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

    def on_advisory(self, advisory: Advisory) -> None:
        self.rerun.log_alarm(advisory.to_dict(), kind="advisory")

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
