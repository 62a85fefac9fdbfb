"""What a mapping decodes to, for commissioning (``edge-monitor check-mapping``; docs/CONNECTING.md).

:class:`SignalCheck` takes decoded samples (a foreign source's, or our frames' after ingest), keeps per
joint the count, rate and range of every quantity, the steady speeds a plateau detector with no
configured levels finds on each joint, and — through a :class:`SampleStream` with the mapping's
labeller — the cycles found. :meth:`SignalCheck.problems` lists what makes the mapping unusable (a joint
without frames, values no robot has); :meth:`SignalCheck.report` is the JSON-able summary.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import NDArray

from edge_monitor.features.segmentation import PlateauConfig, PlateauDetector
from edge_monitor.sources.sample_stream import PLAUSIBLE, SampleStream
from edge_monitor.sources.samples import DecodedSamples


@dataclass
class _Range:
    n: int = 0
    low: float = math.inf
    high: float = -math.inf
    first: float = math.inf
    last: float = -math.inf

    def add(self, time: NDArray[np.float64], values: NDArray[np.float64]) -> None:
        ok = np.isfinite(values)
        if ok.any():
            self.n += int(ok.sum())
            self.low, self.high = min(self.low, float(values[ok].min())), max(self.high, float(values[ok].max()))
            self.first, self.last = min(self.first, float(time[ok][0])), max(self.last, float(time[ok][-1]))

    def to_dict(self) -> dict[str, Any] | None:
        if self.n == 0:
            return None
        span = self.last - self.first
        return {"samples": self.n, "min": self.low, "max": self.high,
                "rate_hz": (self.n - 1) / span if span > 0 else None}


@dataclass
class _JointCheck:
    ranges: dict[str, _Range] = field(default_factory=lambda: {q: _Range() for q in PLAUSIBLE})
    plateaus: PlateauDetector | None = None


class SignalCheck:
    """Accumulates what the source decodes (see the module docstring)."""

    def __init__(self, joints: list[int], rate_hz: float, stream: SampleStream | None,
                 plateau: PlateauConfig, descriptions: dict[int, dict[str, str]] | None = None) -> None:
        self.rate_hz = rate_hz
        self.stream = stream
        self.descriptions = descriptions or {}
        self.joints = {j: _JointCheck(plateaus=PlateauDetector(PlateauConfig(
            **{**plateau.fingerprint(), "speeds": ()}), rate_hz)) for j in joints}
        self._t0: float | None = None

    def update(self, decoded: DecodedSamples) -> None:
        for j, cols in decoded.joints.items():
            check = self.joints.setdefault(j, _JointCheck(plateaus=PlateauDetector(PlateauConfig(), self.rate_hz)))
            check.ranges["speed"].add(cols.time, cols.speed)
            check.ranges["torque"].add(cols.time, cols.torque)
            if cols.time.size:
                self._t0 = float(cols.time[0]) if self._t0 is None else self._t0
                ticks = np.rint((cols.time - self._t0) * self.rate_hz).astype(np.int64)
                assert check.plateaus is not None
                check.plateaus.update(ticks, cols.speed, cols.torque)
        for j, st in decoded.status.items():
            check = self.joints.setdefault(j, _JointCheck())
            check.ranges["load"].add(st.time, st.load)
            check.ranges["temperature"].add(st.time, st.temperature)
        if self.stream is not None:
            self.stream.update(decoded)

    def problems(self) -> list[str]:
        out = []
        for j, check in sorted(self.joints.items()):
            where = self.descriptions.get(j, {}).get("speed", "its speed/torque frames")
            if check.ranges["speed"].n == 0:
                out.append(f"joint {j}: no samples ({where}): wrong message/identifier, node id, or the drive "
                           "is not in operation enabled")
                continue
            for q, limit in PLAUSIBLE.items():
                r = check.ranges[q]
                if r.n and max(abs(r.low), abs(r.high)) > limit:
                    out.append(f"joint {j}: {q} reaches {max(abs(r.low), abs(r.high)):.4g}, beyond {limit:g} "
                               f"({_UNITS[q]}): check its unit, scale or reference torque")
        return out

    def report(self) -> dict[str, Any]:
        joints = {}
        for j, check in sorted(self.joints.items()):
            ranges = {q: r.to_dict() for q, r in check.ranges.items()}
            levels = sorted(check.plateaus.level_speeds) if check.plateaus is not None else []
            joints[str(j)] = {"signals": self.descriptions.get(j, {}), **ranges,
                              "missing": [q for q in ("temperature", "load") if ranges[q] is None],
                              "steady_speeds": [round(v, 2) for v in levels]}
        out: dict[str, Any] = {"joints": joints, "problems": self.problems()}
        if self.stream is not None:
            self.stream.flush()
            out["cycles"] = self.stream.counters()
        return out


_UNITS = {"speed": "rad/s", "torque": "fraction of T_ref", "load": "fraction of T_ref", "temperature": "°C"}
