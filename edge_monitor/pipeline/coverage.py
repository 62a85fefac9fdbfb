"""Coverage: how much of the time each detector of a joint really tests, and why not when it does not
(docs/DETECTION.md, "Coverage").

A detector *tests* a cycle when it computes its statistic on the cycle's value against a threshold.
Every other cycle has one reason, from this list (:data:`REASONS`):

* ``learning``: the detector collects a nominal (after a maintenance or a relearn; the first learning
  of a joint is not counted: coverage starts when the detector leaves it);
* ``model``: the joint relearns its friction model (after a maintenance), so no quantity has a value;
* ``calibrating``: the nominal is learned, its threshold is being computed;
* ``held_warm`` / ``held_cold`` / ``held``: the detector holds because the joint is warmer / colder than
  its models cover (or for another stated reason);
* ``no_value``: the cycle gave no usable value (too few samples, a value that is not finite);
* ``partial``: the cycle's start or end was not seen, it feeds no detector.

Per detector :class:`DetectorCoverage` keeps the counts since its first monitoring cycle and a ring of
the last ``window`` cycles' reasons (bounded memory: one byte per cycle of the window). The share of
tested cycles overall (``share``) and over the window (``recent``) go into every symptom record
(``coverage`` section), the health record and the run summary.
"""

from __future__ import annotations

from typing import Any, Iterable

import numpy as np

from edge_monitor.records import Decision, is_count

#: Why a cycle was or was not tested; the index is the code kept in the ring.
REASONS = ("tested", "learning", "model", "calibrating", "held_warm", "held_cold", "held", "no_value", "partial")
TESTED = "tested"
#: Reasons of the cycles before a detector's first monitoring cycle (not counted).
FIRST_LEARNING = ("learning", "model")
#: How a saved ring writes each cycle's reason (index into :data:`REASONS`; the last: not yet filled, −1).
RING_CODES = "tlmcwkhnp."
#: Cycles of the recent window (about one day at 300 test cycles a day).
DEFAULT_WINDOW = 300
#: Longest window a saved state may claim (bounds the memory a damaged state file can ask for).
MAX_WINDOW = 100_000


def coverage_reason(decision: Decision, learning: bool, finite: bool, held: str = "") -> str:
    """Why a detector did or did not test this cycle: ``decision`` is its answer, ``learning`` whether it
    was learning before the cycle, ``finite`` whether the cycle's value was, ``held`` its hold reason."""
    if held:
        return "held_warm" if "above" in held else "held_cold" if "below" in held else "held"
    if learning or decision.state == "learning" or decision.reason.startswith("nominal density learned"):
        return "learning"          # (the last: the cycle whose value completed a new nominal)
    if not finite:
        return "no_value"
    if decision.statistic is None:
        return "no_value"          # a finite value the detector could not use (too large to transform)
    return TESTED if decision.threshold is not None else "calibrating"


class DetectorCoverage:
    """``update(reason) -> None`` per cycle once the detector has monitored; counts and a recent ring."""

    def __init__(self, window: int = DEFAULT_WINDOW) -> None:
        if not 1 <= window <= MAX_WINDOW:
            raise ValueError(f"coverage window: need 1 … {MAX_WINDOW} cycles, got {window!r}")
        self.counts = dict.fromkeys(REASONS, 0)
        self.ring = np.full(window, -1, dtype=np.int8)    # reason codes, -1: not yet filled
        self.position = 0
        self.started = False

    def update(self, reason: str) -> None:
        """One cycle's reason (one of :data:`REASONS`). Counting starts once the detector has left its
        first learning (the first cycle whose reason is neither ``learning`` nor ``model``)."""
        if reason not in self.counts:
            raise ValueError(f"unknown coverage reason {reason!r}; known: {', '.join(REASONS)}")
        self.started |= reason not in FIRST_LEARNING
        if not self.started:
            return
        self.counts[reason] += 1
        self.ring[self.position % self.ring.size] = REASONS.index(reason)
        self.position += 1

    @property
    def cycles(self) -> int:
        """Cycles counted since the detector left its first learning."""
        return sum(self.counts.values())

    @property
    def share(self) -> float | None:
        """Share of the counted cycles that were tested (None before the first)."""
        return self.counts[TESTED] / self.cycles if self.cycles else None

    @property
    def recent(self) -> float | None:
        """Share tested over the last ``window`` counted cycles (None before the first)."""
        filled = self.ring[self.ring >= 0]
        return float(np.mean(filled == 0)) if filled.size else None

    def not_tested(self) -> dict[str, int]:
        """Counted cycles that were not tested, by reason (reasons that never occurred left out)."""
        return {r: n for r, n in self.counts.items() if r != TESTED and n}

    def summary(self) -> dict[str, Any]:
        return {"share": self.share, "recent": self.recent, "cycles": self.cycles, "not_tested": self.not_tested()}

    def state_dict(self) -> dict[str, Any]:
        """Counts, and the ring as one character per cycle (:data:`RING_CODES`: a few hundred bytes of JSON)."""
        return {"counts": dict(self.counts), "ring": "".join(RING_CODES[c] for c in self.ring.tolist()),
                "position": self.position, "started": self.started}

    @classmethod
    def from_state(cls, state: Any, window: int = DEFAULT_WINDOW) -> "DetectorCoverage":
        """From :meth:`state_dict`; anything unusable starts afresh (coverage is a report, not a model)."""
        out = cls(window)
        saved = state if isinstance(state, dict) else {}
        counts, ring, position = saved.get("counts"), saved.get("ring"), saved.get("position")
        if not (isinstance(counts, dict) and isinstance(ring, str) and len(ring) == window
                and is_count(position) and all(is_count(counts.get(r, 0)) for r in REASONS)
                and all(c in RING_CODES for c in ring)):
            return out
        out.counts = {r: int(counts.get(r, 0)) for r in REASONS}
        out.ring = np.asarray([RING_CODES.index(c) if c != "." else -1 for c in ring], dtype=np.int8)
        out.position = position
        out.started = saved.get("started") is True
        return out


class Coverage:
    """The coverage of every detector of one joint (see the module docstring)."""

    def __init__(self, quantities: Iterable[str], window: int = DEFAULT_WINDOW) -> None:
        self.window = window
        self.detectors = {q: DetectorCoverage(window) for q in quantities}

    def update(self, reasons: dict[str, str]) -> None:
        """One cycle: the reason of each detector (quantities not named are not counted this cycle)."""
        for quantity, reason in reasons.items():
            tracker = self.detectors.get(quantity)
            if tracker is not None:
                tracker.update(reason)

    def section(self, reasons: dict[str, str]) -> dict[str, Any]:
        """The symptom record's ``coverage`` section: per quantity this cycle's reason, the share tested
        since the detector first monitored and over the recent window."""
        return {q: {"status": reasons.get(q), "share": c.share, "recent": c.recent}
                for q, c in self.detectors.items()}

    def summary(self) -> dict[str, Any]:
        """Per quantity: share, recent share, cycles counted, and the untested cycles by reason."""
        return {q: c.summary() for q, c in self.detectors.items()}

    def state_dict(self) -> dict[str, Any]:
        return {"window": self.window, "detectors": {q: c.state_dict() for q, c in self.detectors.items()}}

    @classmethod
    def from_state(cls, quantities: Iterable[str], state: Any) -> "Coverage":
        saved: dict[str, Any] = state if isinstance(state, dict) else {}
        given = saved.get("window")
        window = given if is_count(given) and 1 <= given <= MAX_WINDOW else DEFAULT_WINDOW
        out = cls(quantities, window)
        detectors: dict[str, Any] = saved["detectors"] if isinstance(saved.get("detectors"), dict) else {}
        out.detectors = {q: DetectorCoverage.from_state(detectors.get(q), window) for q in out.detectors}
        return out

