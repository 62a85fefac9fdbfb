"""Whether data is flowing: frames and samples per joint since the last health record, and how long ago the
last ones came (the health record's ``data_flowing`` and ``data_flow``; docs/OPERATIONS.md).

A dead CAN bus, a pulled cable or a controller that sends only frames nothing decodes looks like a quiet
healthy agent unless someone says so: :class:`DataFlow` says ``data_flowing: false`` once no sample has
arrived for ``timeout_s`` (the agent config's ``data_timeout_s``; 0 turns the judgement off). The live
loop feeds it each block's frame count and ingested samples; the systemd watchdog and the container's
health check follow ``flowing``.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

from edge_monitor.sources.samples import IngestBlock


@dataclass
class DataFlow:
    """Counts since the last :meth:`interval` and the times of the last frame and sample (monotonic s)."""

    timeout_s: float
    started: float
    frames: int = 0
    samples: dict[int, int] = field(default_factory=dict)
    last_frame: float | None = None
    last_sample: float | None = None
    _interval_start: float | None = None

    def add(self, now: float, frames: int, block: IngestBlock) -> None:
        """One processed block: ``frames`` frames, ``block`` their samples."""
        if frames:
            self.frames += frames
            self.last_frame = now
        for run in block.runs:
            for joint, samples in run.samples.items():
                n = int(samples.tick.size)
                if n:
                    self.samples[joint] = self.samples.get(joint, 0) + n
                    self.last_sample = now

    def flowing(self, now: float) -> bool:
        """A sample arrived within ``timeout_s`` (in the first ``timeout_s`` after the start: still waiting,
        flowing); always True with ``timeout_s`` 0."""
        if self.timeout_s <= 0:
            return True
        return now - (self.last_sample if self.last_sample is not None else self.started) <= self.timeout_s

    def interval(self, now: float, reset: bool = True) -> dict[str, Any]:
        """The health record's fields for the interval since the last reset (``reset``: a new one begins)."""
        start = self._interval_start if self._interval_start is not None else self.started

        def ago(t: float | None) -> float | None:
            return None if t is None else now - t
        out = {"data_flowing": self.flowing(now),
               "data_flow": {"interval_s": now - start, "frames": self.frames,
                             "samples": {str(j): n for j, n in sorted(self.samples.items())},
                             "since_frame_s": ago(self.last_frame), "since_sample_s": ago(self.last_sample),
                             "timeout_s": self.timeout_s}}
        if reset:
            self.frames, self.samples, self._interval_start = 0, {j: 0 for j in self.samples}, now
        return out
