"""What a mapping decodes to, for commissioning (``edge-monitor check-mapping``; docs/CONNECTING.md).

:class:`SignalCheck` takes decoded samples (a foreign source's, or our frames' after ingest), keeps per
joint the count, rate and range of every quantity, the steady speeds a plateau detector with no
configured levels finds on each joint, and — through a :class:`SampleStream` with the mapping's
labeller — the cycles found. :meth:`SignalCheck.problems` lists what makes the mapping unusable (a joint
without frames, values no robot has in either direction — beyond :data:`PLAUSIBLE` or never above
:data:`LEAST` —, no cycle found, cycle marks that are no counter, frames cut short or failing their E2E
check); :meth:`SignalCheck.report` is the JSON-able summary, with the test cycle's levels in its order
(:mod:`cycle_levels`) for ``[cycles] speeds``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import NDArray

from edge_monitor.features.segmentation import PlateauConfig, PlateauDetector
from edge_monitor.sources.cycle_levels import CycleLevels
from edge_monitor.sources.sample_stream import PLAUSIBLE, SampleStream
from edge_monitor.sources.samples import DecodedSamples

#: The largest |value| a joint shows in a capture of test cycles is at least this (speed [rad/s]: the test
#: cycle moves; torque [fraction of T_ref]: a moving motor needs some); temperature [°C] not below it.
LEAST = {"speed": 0.5, "torque": 1e-3}
COLDEST_C = -50.0
#: Share of a mapping's frames that may be cut short or fail E2E (a damaged frame now and then) [1].
DAMAGED_SHARE = 0.01
#: Cycle marks dropped or not taken before the cycle signal is called no cycle counter.
MARKS_TOLERATED = 10


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
    levels: CycleLevels = field(default_factory=CycleLevels)
    not_finite: int = 0


class SignalCheck:
    """Accumulates what the source decodes (see the module docstring)."""

    def __init__(self, joints: list[int], rate_hz: float, stream: SampleStream | None,
                 plateau: PlateauConfig, descriptions: dict[int, dict[str, str]] | None = None,
                 frames: Any = None, reference_joint: int | None = None) -> None:
        self.rate_hz = rate_hz
        self.stream = stream
        self.descriptions = descriptions or {}
        self.frames = frames               # the decoder's counters (frames_total, unknown_id, malformed, …)
        self.reference_joint = min(joints) if reference_joint is None and joints else reference_joint
        self.cycles_seen: set[int] | None = None     # our frames: the cycles their status frames gave
        self.speeds_missing = False                   # a mapping that finds cycles from speeds it does not state
        self.joints = {j: _JointCheck(plateaus=PlateauDetector(PlateauConfig(
            **{**plateau.fingerprint(), "speeds": ()}), rate_hz)) for j in joints}
        self._t0: float | None = None

    def update(self, decoded: DecodedSamples) -> None:
        for j, cols in decoded.joints.items():
            check = self.joints.setdefault(j, _JointCheck(plateaus=PlateauDetector(PlateauConfig(), self.rate_hz)))
            check.ranges["speed"].add(cols.time, cols.speed)
            check.ranges["torque"].add(cols.time, cols.torque)
            check.not_finite += int((~(np.isfinite(cols.speed) & np.isfinite(cols.torque))).sum())
            if cols.time.size:
                self._t0 = float(cols.time[0]) if self._t0 is None else self._t0
                ticks = np.rint((cols.time - self._t0) * self.rate_hz).astype(np.int64)
                assert check.plateaus is not None
                check.levels.add(check.plateaus.update(ticks, cols.speed, cols.torque))
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
            if check.ranges["speed"].n == 0 or check.ranges["torque"].n == 0:
                out.append(f"joint {j}: no samples ({where}): wrong message/identifier, node id, unit or scale, or "
                           "the drive is not in operation enabled")
                continue
            out += [f"joint {j}: {p}" for p in _range_problems(check)]
        out += self._frame_problems() + self._cycle_problems()
        if self.speeds_missing:
            found = self.levels()["speeds"]
            out.append("[cycles] speeds is missing: " + (f"set speeds = [{', '.join(map(str, found))}] (the test "
                       f"cycle's levels on joint {self.reference_joint}, in its order)" if found else
                       "no test-cycle levels found in the capture; capture whole test cycles"))
        return out

    def _frame_problems(self) -> list[str]:
        """Frames of the mapping cut short (malformed) or failing their E2E check, beyond a stray few."""
        c = self.frames
        if c is None:
            return []
        mapped = max(c.frames_total - c.unknown_id, 1)
        out = []
        for name, count, fix in (("malformed", c.malformed, "shorter than their mapping: the drive's PDO mapping "
                                  "or the DBC's message length differs from the controller's"),
                                 ("crc_errors", c.crc_errors, "failing their E2E check: the profile, data ID or "
                                  "the message has no E2E protection")):
            if count > DAMAGED_SHARE * mapped:
                out.append(f"{count} of {mapped} frames ({name}) are {fix}")
        return out

    def _cycle_problems(self) -> list[str]:
        if self.stream is None:
            seen = self.cycles_seen
            return [f"no whole cycle found ({len(seen)} started): capture at least one whole test cycle (from one "
                    "start to the next)"] if seen is not None and len(seen) < 2 else []
        self.stream.flush()
        c = self.stream.counters()
        out = []
        if c.get("bad_marks", 0) > MARKS_TOLERATED or c.get("cycle_jumps", 0) > MARKS_TOLERATED:
            out.append(f"the cycle marks are no cycle counter: {c.get('bad_marks', 0)} are not cycle/segment numbers "
                       f"(integers ≥ 0) and {c.get('cycle_jumps', 0)} jumped where no cycle can end: map the "
                       "controller's cycle counter, or find cycles from the motion ([cycles] from = \"motion\")")
        if c.get("cycles_found", 0) < 2:          # a whole cycle: from one start to the next
            out.append(f"no whole cycle found ({c.get('cycles_found', 0)} started; cycles from the {c.get('method')}): "
                       "capture at least one whole test cycle (from one start to the next), and check [cycles] "
                       "(speeds in the test cycle's order, the trigger value, the cycle signal)")
        return out

    def levels(self) -> dict[str, list[float]]:
        """The test cycle's levels on the reference joint, in its order, and the production speeds left out."""
        check = self.joints.get(self.reference_joint) if self.reference_joint is not None else None
        if check is None:
            return {"speeds": [], "production": []}
        found = check.levels.suggestion()
        return {"speeds": found.speeds, "production": found.production}

    def report(self) -> dict[str, Any]:
        joints = {}
        for j, check in sorted(self.joints.items()):
            ranges = {q: r.to_dict() for q, r in check.ranges.items()}
            levels = sorted(check.plateaus.level_speeds) if check.plateaus is not None else []
            joints[str(j)] = {"signals": self.descriptions.get(j, {}), **ranges,
                              "missing": [q for q in ("temperature", "load") if ranges[q] is None],
                              "steady_speeds": [round(v, 2) for v in levels], "not_finite": check.not_finite}
        out: dict[str, Any] = {"joints": joints, "problems": self.problems(), "test_cycle_levels": self.levels()}
        if self.frames is not None:
            out["frames"] = {k: v for k, v in vars(self.frames).items() if isinstance(v, int)}
        if self.stream is not None:
            out["cycles"] = self.stream.counters()
        return out


def _range_problems(check: _JointCheck) -> list[str]:
    """Values no robot has: beyond :data:`PLAUSIBLE`, never above :data:`LEAST`, colder than
    :data:`COLDEST_C`, or mostly not finite."""
    out = []
    for q, limit in PLAUSIBLE.items():
        r = check.ranges[q]
        if not r.n:
            continue
        largest = max(abs(r.low), abs(r.high))
        if largest > limit:
            out.append(f"{q} reaches {largest:.4g}, beyond {limit:g} ({_UNITS[q]}): check its unit, scale or "
                       "reference torque")
        elif q in LEAST and largest < LEAST[q]:
            out.append(f"{q} never exceeds {largest:.4g} ({_UNITS[q]}), below {LEAST[q]:g}: the robot did not move "
                       "its test cycle in the capture, or its unit, scale, velocity factor or reference torque is "
                       "wrong")
        if q == "temperature" and r.low < COLDEST_C:
            out.append(f"temperature falls to {r.low:.4g} °C, below {COLDEST_C:g} °C: check its unit (K?) or scale")
    samples = check.ranges["speed"].n + check.not_finite
    if check.not_finite > samples / 2:
        out.append(f"{check.not_finite} of {samples} samples have no finite speed or torque: check the scale")
    return out


_UNITS = {"speed": "rad/s", "torque": "fraction of T_ref", "load": "fraction of T_ref", "temperature": "°C"}
