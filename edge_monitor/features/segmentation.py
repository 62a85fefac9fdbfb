"""Constant-speed plateau detection from the motor speed signal (docs/ALGORITHMS.md §2).

Which speed level a sample belongs to comes, in order of preference, from the controller's segment
code (speed level k is segment k + 1, docs/PROTOCOL.md: no configuration needed, the datum speed is
the measured plateau speed), from the configured ``speeds`` (magnitude, both directions, with
hysteresis), or, with neither, from levels discovered in the steady runs of the speed signal (a
steady run at a speed no known level matches registers a new level). Runs of one label form
plateaus, the acceleration
transient at the start (``settle_s``) and a short guard before the end (``guard_s``, the
deceleration torque starts while the speed is still inside the band) are discarded, and the steady
part is reduced to running moments. Memory is O(1) per joint; blocks are processed in numpy.

Units: speed rad/s (motor side), torque dimensionless, time in controller ticks.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, field
from typing import Any

import numpy as np
from numpy.typing import NDArray

from edge_monitor.errors import require, shown
from edge_monitor.records import is_finite_number
from protocol.frames import MAX_SPEED_LEVELS, SEGMENT_PRODUCTION

#: Label of samples at an (apparently) constant speed that matches no configured level.
UNMATCHED = 10_000


@dataclass(frozen=True)
class PlateauConfig:
    """Plateau detection settings (the ``[segmentation]`` table). Speeds in rad/s, durations in s.

    Validated here, once; a bad value raises :class:`ConfigError` naming ``segmentation.<field>``.
    """

    speeds: tuple[float, ...] = ()          # empty: levels from the segment codes (or discovered)
    tolerance_rel: float = 0.02      # enter a level when |v| is within rel·v + abs of it
    tolerance_abs: float = 0.3
    hysteresis: float = 2.0          # stay on a level while within hysteresis × the entry band
    settle_s: float = 0.25           # discarded at the start of each plateau
    guard_s: float = 0.02            # discarded at the end of each plateau
    min_steady_s: float = 0.3        # shorter steady parts are "plateau cut short"
    unmatched_min_speed: float = 1.0  # |v| above which a steady unmatched run is counted

    def __post_init__(self) -> None:
        speeds = np.asarray(self.speeds, dtype=float)
        require(speeds.size <= MAX_SPEED_LEVELS, "segmentation.speeds",
                f"need at most {MAX_SPEED_LEVELS} speed levels (or none: from the segment codes), got {speeds.size}")
        require(bool(np.all(np.isfinite(speeds)) and np.all(speeds > 0)), "segmentation.speeds",
                f"need positive finite speeds in rad/s, got {list(self.speeds)}")
        require(bool(np.all(np.diff(np.sort(speeds)) > 0)), "segmentation.speeds",
                f"speeds must be distinct, got {list(self.speeds)}")
        for name in ("tolerance_rel", "hysteresis", "min_steady_s"):
            require(is_finite_number(getattr(self, name)) and getattr(self, name) > 0, f"segmentation.{name}",
                    f"must be a finite number > 0, got {shown(getattr(self, name))}")
        for name in ("tolerance_abs", "settle_s", "guard_s", "unmatched_min_speed"):
            require(is_finite_number(getattr(self, name)) and getattr(self, name) >= 0, f"segmentation.{name}",
                    f"must be a finite number >= 0, got {shown(getattr(self, name))}")
        for name in ("settle_s", "guard_s", "min_steady_s"):
            require(getattr(self, name) <= 60.0, f"segmentation.{name}", f"must be <= 60 s, got {getattr(self, name)}")

    def fingerprint(self) -> dict[str, Any]:
        return {**asdict(self), "speeds": list(self.speeds)}


@dataclass
class PlateauStat:
    """Moments of the steady part of one constant-speed run (one direction of one level)."""

    level: int            # index into PlateauConfig.speeds
    direction: int        # +1 or -1
    n: int
    mean: float           # mean torque
    m2: float             # sum of squared deviations
    lag1: float           # lag-1 autocorrelation of the torque samples (for the standard error)
    tick_start: int
    tick_end: int
    speed_mean: float

    @property
    def variance(self) -> float:
        return self.m2 / (self.n - 1) if self.n > 1 else float("nan")


@dataclass
class _RunAccumulator:
    """Running moments of committed steady samples of the current run."""

    n: int = 0
    total: float = 0.0
    total_sq: float = 0.0
    lag_products: float = 0.0
    first: float = 0.0
    last: float = 0.0
    speed_total: float = 0.0

    def commit(self, torque: NDArray[np.float64], speed: NDArray[np.float64]) -> None:
        if torque.size == 0:
            return
        if self.n == 0:
            self.first = float(torque[0])
        else:
            self.lag_products += self.last * float(torque[0])
        self.lag_products += float(np.dot(torque[:-1], torque[1:]))
        self.n += torque.size
        self.total += float(torque.sum())
        self.total_sq += float(np.dot(torque, torque))
        self.last = float(torque[-1])
        self.speed_total += float(speed.sum())

    def moments(self) -> tuple[float, float, float]:
        """(mean, M2, lag-1 autocorrelation) of the committed samples."""
        n = self.n
        mean = self.total / n
        m2 = max(self.total_sq - n * mean * mean, 0.0)
        if n < 3 or m2 <= 0:
            return mean, m2, 0.0
        # Σ (x_i − m)(x_{i+1} − m) over n−1 pairs, from raw sums.
        cross = self.lag_products - mean * (2 * self.total - self.first - self.last) + (n - 1) * mean * mean
        return mean, m2, float(np.clip(cross / m2, -1.0, 1.0))


@dataclass
class SegmentationCounters:
    plateaus: int = 0
    cut_short: int = 0
    unmatched: int = 0
    nonfinite_samples: int = 0
    levels_discovered: int = 0

    def as_dict(self) -> dict[str, int]:
        return dict(self.__dict__)


#: Samples labelled at once by :meth:`PlateauDetector.update` (bounds the re-labelling after a plateau).
CLASSIFY_CHUNK = 2048


@dataclass
class PlateauDetector:
    """Streaming plateau detector for one joint: ``update(block) -> list[PlateauStat]``.

    ``rate_hz`` is the controller tick rate [Hz]: durations of the config are converted to ticks.
    """

    config: PlateauConfig = field(default_factory=PlateauConfig)
    rate_hz: float = 500.0
    counters: SegmentationCounters = field(default_factory=SegmentationCounters)
    _label: int = 0
    _run_len: int = 0
    _run_tick_start: int = 0
    _last_tick: int = 0
    _acc: _RunAccumulator = field(default_factory=_RunAccumulator)
    _pending_t: NDArray[np.float64] = field(default_factory=lambda: np.empty(0))
    _pending_v: NDArray[np.float64] = field(default_factory=lambda: np.empty(0))

    _levels: list[float] = field(default_factory=list)     # discovered level speeds (no config, no segments)
    _last_speed: float = 0.0
    _unmatched_sum: float = 0.0
    _unmatched_n: int = 0
    _classification_version: int = 0      # bumped whenever a finished run changes how samples are labelled

    def __post_init__(self) -> None:
        self.auto = len(self.config.speeds) == 0
        self._segment_speed = np.full(MAX_SPEED_LEVELS + 1, np.nan)     # measured plateau speed per segment
        self._set_levels(list(self.config.speeds) if not self.auto else self._levels)
        self._settle = self._ticks(self.config.settle_s)
        self._guard = self._ticks(self.config.guard_s)
        self._min_steady = max(self._ticks(self.config.min_steady_s), 2)

    def _ticks(self, seconds: float) -> int:
        return int(round(seconds * self.rate_hz))

    def _set_levels(self, speeds: list[float]) -> None:
        levels = np.asarray(speeds, dtype=float)
        order = np.argsort(levels)
        self._sorted_speeds = levels[order]
        self._sorted_index = order
        self._band = self.config.tolerance_rel * self._sorted_speeds + self.config.tolerance_abs

    @property
    def level_speeds(self) -> tuple[float, ...]:
        """Speeds of the levels by index [rad/s]: configured or discovered (empty with segment codes)."""
        return tuple(self.config.speeds) if not self.auto else tuple(self._levels)

    @property
    def open_run_start(self) -> int | None:
        """Tick at which the run on a level now in progress began (None: no level run is open). Samples
        from there on may still become part of a plateau."""
        return self._run_tick_start if self._label != 0 and self._label != UNMATCHED else None

    def _steady(self, speed: NDArray[np.float64]) -> NDArray[np.bool_]:
        """Small sample-to-sample change at a speed well above standstill (across blocks)."""
        steady = np.abs(np.diff(speed, prepend=self._last_speed)) < self.config.tolerance_abs
        return steady & (np.abs(speed) > self.config.unmatched_min_speed)

    def classify_segments(self, speed: NDArray[np.float64], segment: NDArray[np.int64]) -> NDArray[np.int64]:
        """Label per sample from the controller's segment codes: ±segment on a steady part of speed
        level segment − 1 (segments 1 … 64), else 0. Once a level's plateau speed has been measured,
        only samples within its band count (slow ramps stay out)."""
        level = np.where((segment >= 1) & (segment <= MAX_SPEED_LEVELS), segment, 0).astype(np.int64)
        ok = (level > 0) & self._steady(speed)
        known = self._segment_speed[level]
        band = self.config.tolerance_rel * known + self.config.tolerance_abs
        ok &= np.isnan(known) | (np.abs(np.abs(speed) - known) <= band * self.config.hysteresis)
        return np.where(ok, np.sign(speed).astype(np.int64) * level, 0)

    # ------------------------------------------------------------------ classification
    def classify(self, speed: NDArray[np.float64], exclude: NDArray[np.bool_] | None = None) -> NDArray[np.int64]:
        """Label per sample: ±(level+1) on a level, UNMATCHED (steady, no level) or 0, with hysteresis."""
        a = np.abs(speed)
        levels = self._sorted_speeds
        if levels.size == 0:
            labels = np.where(self._steady(speed), UNMATCHED, 0)
            return labels if exclude is None else np.where(exclude, 0, labels)
        right = np.minimum(np.searchsorted(levels, a), levels.size - 1)
        left = np.maximum(right - 1, 0)
        nearest = np.where(np.abs(a - levels[left]) <= np.abs(a - levels[right]), left, right)
        dist = np.abs(a - self._sorted_speeds[nearest])
        band = self._band[nearest]
        level_label = np.sign(speed).astype(np.int64) * (self._sorted_index[nearest] + 1)
        inner = dist <= band
        outer = dist <= band * self.config.hysteresis
        if exclude is not None:             # an excluded sample is on no level, and a chain cannot pass it
            inner, outer = inner & ~exclude, outer & ~exclude
        labels = np.where(inner, level_label, 0)
        labels = np.where(self._stays(inner, outer, level_label), level_label, labels)
        # Steady but unmatched: small sample-to-sample change at a speed well above standstill.
        labels = np.where((labels == 0) & self._steady(speed), UNMATCHED, labels)
        if exclude is not None:
            labels = np.where(exclude, 0, labels)
        return labels

    def _stays(self, inner: NDArray[np.bool_], outer: NDArray[np.bool_],
               level_label: NDArray[np.int64]) -> NDArray[np.bool_]:
        """Hysteresis: the samples that stay on their level while only in its outer band, i.e. whose
        previous sample is on the same level (inner, or staying itself; before the block: the label in
        force). Evaluated sample by sample this is a recurrence; here each chain of consecutive
        outer-only samples of one level stays iff the sample just before the chain is an inner sample
        of that level."""
        n = inner.size
        between = outer & ~inner
        first = between.copy()              # the first sample of each chain
        first[1:] &= ~between[:-1] | (level_label[1:] != level_label[:-1])
        start = np.where(first, np.arange(n), 0)
        np.maximum.accumulate(start, out=start)
        before = start - 1                  # the sample before the chain (−1: the previous block)
        prev = np.maximum(before, 0)
        entered = np.where(before >= 0, inner[prev] & (level_label[prev] == level_label), self._label == level_label)
        return between & entered

    # ------------------------------------------------------------------ streaming
    def update(self, tick: NDArray[np.int64], speed: NDArray[np.float64], torque: NDArray[np.float64],
               segment: NDArray[np.int64] | None = None) -> list[PlateauStat]:
        """Consume one block of samples of this joint (ordered by tick); return finished plateaus.

        ``segment``: the controller's segment code per sample (None without status frames). It labels
        the levels when no speeds are configured, and keeps the production motion out of plateaus.
        """
        if tick.size == 0:
            return []
        finite = np.isfinite(speed) & np.isfinite(torque)
        if not finite.all():
            self.counters.nonfinite_samples += int((~finite).sum())
            speed = np.where(finite, speed, 0.0)
        out: list[PlateauStat] = []
        start = 0
        while start < tick.size:
            # at most CLASSIFY_CHUNK samples are labelled at once: a finished plateau that changes the
            # labelling makes the rest be labelled again, so a long block would cost O(plateaus · block)
            part = slice(start, start + CLASSIFY_CHUNK)
            labels = self._labels(speed[part], finite[part], None if segment is None else segment[part])
            done = self._consume(tick[part], speed[part], torque[part], labels, out)
            self._last_speed = float(speed[start + done - 1])
            start += done
        self._last_tick = int(tick[-1])
        return out

    def _labels(self, speed: NDArray[np.float64], finite: NDArray[np.bool_],
                segment: NDArray[np.int64] | None) -> NDArray[np.int64]:
        if self.auto and segment is not None:
            return np.where(finite, self.classify_segments(speed, segment), 0)
        exclude = ~finite if segment is None else (~finite | (segment == SEGMENT_PRODUCTION))
        return self.classify(speed, exclude)

    def _consume(self, tick: NDArray[np.int64], speed: NDArray[np.float64], torque: NDArray[np.float64],
                 labels: NDArray[np.int64], out: list[PlateauStat]) -> int:
        """Runs of ``labels`` into plateaus; returns how many samples were consumed. It stops after the
        first sample of a new run when ending the previous run changed how samples are classified
        (a level's measured speed, a discovered level): the rest is classified again, as it would be
        in a later block, so the plateaus do not depend on how the stream is cut into blocks."""
        change = np.flatnonzero(np.diff(labels, prepend=self._label) != 0)
        starts = np.unique(np.concatenate([[0], change]))
        ends = np.append(starts[1:], labels.size)
        for s, e in zip(starts, ends):
            label = int(labels[s])
            if label != self._label:
                version = self._classification_version
                out.extend(self._end_run())
                self._start_run(label, int(tick[s]))
                if self._classification_version != version and s + 1 < labels.size:
                    self._extend_run(tick[s:s + 1], speed[s:s + 1], torque[s:s + 1])
                    return int(s) + 1
            self._extend_run(tick[s:e], speed[s:e], torque[s:e])
        return int(labels.size)

    def flush(self) -> list[PlateauStat]:
        """End the current run (end of stream)."""
        out = self._end_run()
        self._start_run(0, self._last_tick)
        return out

    def _start_run(self, label: int, tick_start: int) -> None:
        self._label = label
        self._run_len = 0
        self._run_tick_start = tick_start
        self._acc = _RunAccumulator()
        self._pending_t = np.empty(0)
        self._pending_v = np.empty(0)
        self._unmatched_sum, self._unmatched_n = 0.0, 0

    def _extend_run(self, tick: NDArray[np.int64], speed: NDArray[np.float64], torque: NDArray[np.float64]) -> None:
        if self._label == 0:
            self._run_len += tick.size
            return
        pos = (tick - self._run_tick_start)
        steady = pos >= self._settle
        self._run_len += tick.size
        if self._label == UNMATCHED:
            self._unmatched_sum += float(np.abs(speed[steady]).sum())
            self._unmatched_n += int(steady.sum())
            return
        t = np.concatenate([self._pending_t, torque[steady]])
        v = np.concatenate([self._pending_v, speed[steady]])
        keep = min(self._guard, t.size)
        cut = t.size - keep
        self._acc.commit(t[:cut], v[:cut])
        self._pending_t, self._pending_v = t[cut:], v[cut:]
        self._last_tick = int(tick[-1])

    def _end_run(self) -> list[PlateauStat]:
        label = self._label
        if label == 0:
            return []
        if label == UNMATCHED:
            if self._run_len >= self._settle + self._min_steady:
                self.counters.unmatched += 1
                self._discover(self._unmatched_sum / max(self._unmatched_n, 1))
            return []
        if self._acc.n < self._min_steady:
            # Runs much shorter than the settle time are passing crossings, not cut plateaus.
            if self._run_len > self._settle:
                self.counters.cut_short += 1
            return []
        mean, m2, lag1 = self._acc.moments()
        self.counters.plateaus += 1
        measured = abs(self._acc.speed_total / self._acc.n)
        if self.auto and abs(label) <= MAX_SPEED_LEVELS:   # learn the level's speed (segment-code labels)
            known = self._segment_speed[abs(label)]
            self._segment_speed[abs(label)] = measured if np.isnan(known) else 0.8 * known + 0.2 * measured
            self._classification_version += 1
        return [PlateauStat(level=abs(label) - 1, direction=1 if label > 0 else -1, n=self._acc.n, mean=mean,
                            m2=m2, lag1=lag1, tick_start=self._run_tick_start, tick_end=self._last_tick,
                            speed_mean=self._acc.speed_total / self._acc.n)]

    def _discover(self, speed: float) -> None:
        """Without configured speeds and segment codes: a long steady run at a new speed is a level."""
        if self.auto and len(self._levels) < MAX_SPEED_LEVELS and speed > self.config.unmatched_min_speed:
            self._levels.append(round(speed, 3))
            self._set_levels(self._levels)
            self.counters.levels_discovered += 1
            self._classification_version += 1

    # ------------------------------------------------------------------ persistence
    def state_dict(self) -> dict:
        """Counters and discovered levels: a restart begins with no plateau in progress."""
        return {"counters": self.counters.as_dict(), "levels": list(self._levels)}

    @classmethod
    def from_state(cls, config: PlateauConfig, state: dict, rate_hz: float = 500.0) -> "PlateauDetector":
        counts = state.get("counters", {})
        known = {k: int(counts[k]) for k in SegmentationCounters().as_dict() if isinstance(counts.get(k), int)}
        levels = [float(v) for v in state.get("levels", []) if isinstance(v, (int, float)) and 0 < v < 1e4]
        return cls(config=config, rate_hz=rate_hz, counters=SegmentationCounters(**known),
                   _levels=levels[:MAX_SPEED_LEVELS] if len(config.speeds) == 0 else [])
