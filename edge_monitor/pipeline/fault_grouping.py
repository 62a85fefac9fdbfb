"""One alarm per fault: the threshold crossings of one joint's detectors grouped into faults.

A joint watches several quantities (wear, kl_raw, kl_weighted, the joint vector); one worn gearbox
makes several of them cross within a few cycles. What a maintenance person must act on is the fault,
so :class:`FaultTracker` turns the per-detector events of :class:`~edge_monitor.pipeline.detectors.DetectorBank`
into one published record per fault event (docs/OUTPUTS.md, "Alarm record"):

* **raised** — the first crossing while no fault is open: a new fault, id ``"<robot>/<joint>/<cycle>"``
  (the cycle it was raised in; at most one fault is open per joint, so the id is unique);
* **updated** — another detector crosses while the fault is open: the same fault, naming every
  detector that agrees so far with its evidence;
* **chattering** — a detector crosses again within ``chatter_cycles`` after the fault's acknowledgement
  (of that detector, or of the whole fault): the same fault, open again, counted; after that window a
  crossing of a closed fault's joint is a new fault;
* **acknowledged** — an operator judged the latched detectors false: one record naming those
  detectors; the fault closes when none of its detectors stays latched;
* **cleared** — a declared maintenance: one record naming the latched detectors; the fault closes and
  no chatter window follows (the detectors relearn).

The open fault (or the one last acknowledged, for its chatter window) is part of the joint's saved
state, so a restart keeps the fault id and does not raise a second fault for detectors still latched.
"""

from __future__ import annotations

import logging
from collections.abc import Collection, Sequence
from dataclasses import dataclass, field
from typing import Any

from edge_monitor.errors import require
from edge_monitor.records import Alarm

log = logging.getLogger(__name__)

#: Default chatter window [cycles]: a crossing this soon after an acknowledgement is the same fault.
CHATTER_CYCLES = 20
MAX_CHATTER_CYCLES = 1_000_000


@dataclass(frozen=True)
class AlarmConfig:
    """The ``[alarms]`` table. ``chatter_cycles`` [cycles]: a crossing at most this many cycles after a
    fault's acknowledgement is reported as that fault "chattering", not as a new fault (0: never)."""

    chatter_cycles: int = CHATTER_CYCLES

    def __post_init__(self) -> None:
        value = self.chatter_cycles
        require(isinstance(value, int) and not isinstance(value, bool) and 0 <= value <= MAX_CHATTER_CYCLES,
                "alarms.chatter_cycles", f"must be a whole number of cycles 0 … {MAX_CHATTER_CYCLES}, got {value!r}")


@dataclass
class Fault:
    """One fault of a joint: the detector that raised it and the latest evidence of every detector that
    agreed (quantity → :meth:`Alarm.evidence` plus ``crossings``, how often it crossed in this fault)."""

    id: str
    first: str
    evidence: dict[str, dict[str, Any]] = field(default_factory=dict)
    open: bool = True
    acknowledged: dict[str, int] = field(default_factory=dict)   # quantity → cycle of its latest acknowledgement
    closed_at: int | None = None                                  # cycle of the acknowledgement that closed it

    def to_state(self) -> dict[str, Any]:
        return {"id": self.id, "first": self.first, "evidence": self.evidence, "open": self.open,
                "acknowledged": self.acknowledged, "closed_at": self.closed_at}

    @classmethod
    def from_state(cls, state: dict[str, Any]) -> "Fault":
        closed_at = state.get("closed_at")
        evidence = state["evidence"]
        require(isinstance(evidence, dict) and all(isinstance(v, dict) for v in evidence.values()),
                "faults.evidence", "expected quantity → evidence objects")
        return cls(str(state["id"]), str(state["first"]), {str(q): dict(e) for q, e in evidence.items()},
                   bool(state["open"]), {str(q): int(c) for q, c in dict(state.get("acknowledged", {})).items()},
                   None if closed_at is None else int(closed_at))


class FaultTracker:
    """The faults of one joint (see the module docstring); ``raised`` and ``chattering`` count the faults
    raised and the chattering records since the joint was first learned."""

    def __init__(self, config: AlarmConfig, robot: str, joint: int) -> None:
        self.config, self.robot, self.joint = config, robot, joint
        self.fault: Fault | None = None        # the open fault, or the last one acknowledged (chatter window)
        self.raised = 0
        self.chattering = 0

    @property
    def open_fault(self) -> str | None:
        """The id of the open fault, if any."""
        return self.fault.id if self.fault is not None and self.fault.open else None

    def crossings(self, alarms: Sequence[Alarm], cycle: int) -> list[Alarm]:
        """The detector crossings of one cycle (the "raised" alarms of ``DetectorBank.update``, each with its
        cause) → at most one record: "raised", "updated" or "chattering"."""
        if not alarms:
            return []
        fault = self.fault
        if fault is not None and any(self._chatters(fault, a.quantity, cycle) for a in alarms):
            state = "chattering"
            self.chattering += 1
        elif fault is not None and fault.open:
            state = "updated"
        else:
            fault, state = Fault(f"{self.robot}/{self.joint}/{cycle}", alarms[0].quantity), "raised"
            self.raised += 1
        for alarm in alarms:
            crossings = int(fault.evidence.get(alarm.quantity, {}).get("crossings", 0)) + 1
            fault.evidence[alarm.quantity] = {**alarm.evidence(), "crossings": crossings}
        fault.open, fault.closed_at, self.fault = True, None, fault
        return [self._record(fault, state, cycle, tuple(fault.evidence.values()), evidence=True)]

    def acknowledged(self, alarms: Sequence[Alarm], cycle: int, latched: Collection[str]) -> list[Alarm]:
        """The "acknowledged" alarms of ``DetectorBank.acknowledge`` → one record of their fault naming
        them; ``latched``: the joint's detectors still latched (the fault stays open while one of its is)."""
        if not alarms:
            return []
        fault = self._current(alarms)
        for alarm in alarms:
            fault.acknowledged[alarm.quantity] = cycle
        fault.open = any(q in latched for q in fault.evidence)
        fault.closed_at = None if fault.open else cycle
        named = tuple(fault.evidence.get(a.quantity, a.evidence()) for a in alarms)
        return [self._record(fault, "acknowledged", cycle, named)]

    def cleared(self, alarms: Sequence[Alarm], cycle: int) -> list[Alarm]:
        """The "cleared" alarms of ``DetectorBank.reset`` (a maintenance) → one record closing their fault;
        no chatter window follows (the detectors relearn)."""
        if not alarms:
            self.fault = None
            return []
        fault = self._current(alarms)
        fault.open = False
        named = tuple(fault.evidence.get(a.quantity, a.evidence()) for a in alarms)
        record = self._record(fault, "cleared", cycle, named)
        self.fault = None
        return [record]

    def reconcile(self, latched: Collection[str]) -> None:
        """After a restart: an open fault none of whose detectors is latched any more (they relearn, e.g.
        after a config change) is closed without a record."""
        if self.fault is not None and self.fault.open and not any(q in latched for q in self.fault.evidence):
            log.info("joint %d: fault %s closed: none of its detectors is latched after the restart",
                     self.joint, self.fault.id)
            self.fault = None

    def _chatters(self, fault: Fault, quantity: str, cycle: int) -> bool:
        since = fault.acknowledged.get(quantity) if fault.open else fault.closed_at
        return since is not None and cycle - since <= self.config.chatter_cycles

    def _current(self, alarms: Sequence[Alarm]) -> Fault:
        """The open fault; for detectors latched without one (a state saved before faults were kept), a
        fault made of them, named after the earliest cycle they crossed in."""
        if self.fault is None or not self.fault.open:
            since = min((a.cycle for a in alarms), default=0)
            self.fault = Fault(f"{self.robot}/{self.joint}/{since}", alarms[0].quantity,
                               {a.quantity: {**a.evidence(), "crossings": 1} for a in alarms})
        return self.fault

    def _record(self, fault: Fault, state: str, cycle: int, detectors: tuple[dict[str, Any], ...],
                evidence: bool = False) -> Alarm:
        """A published record of ``fault``: ``quantity`` is the detector that raised it; with ``evidence``
        its crossing's statistic, threshold, miss probability, change cycle and cause on the top level
        (as a single detector's alarm had them), else its threshold only."""
        first = fault.evidence.get(fault.first, {})
        if not evidence:
            first = {"threshold": first.get("threshold") if state == "acknowledged" else None}
        return Alarm(self.robot, self.joint, cycle, fault.first, state, first.get("statistic"), first.get("threshold"),
                     first.get("miss_probability"), first.get("change_cycle"), cause=first.get("cause"),
                     fault=fault.id, detectors=detectors, open=fault.open)

    # ------------------------------------------------------------------ persistence
    def state_dict(self) -> dict[str, Any]:
        return {"fault": None if self.fault is None else self.fault.to_state(), "raised": self.raised,
                "chattering": self.chattering}

    @classmethod
    def from_state(cls, config: AlarmConfig, robot: str, joint: int, state: Any) -> "FaultTracker":
        """The tracker saved in ``state``; a fresh one (logged) when it is missing or unusable."""
        tracker = cls(config, robot, joint)
        if state is None:
            return tracker
        try:
            tracker.raised, tracker.chattering = int(state.get("raised", 0)), int(state.get("chattering", 0))
            tracker.fault = None if state.get("fault") is None else Fault.from_state(state["fault"])
        except (AttributeError, KeyError, TypeError, ValueError) as exc:
            log.warning("joint %d: saved faults unusable (%s); starting without an open fault", joint, exc)
            return cls(config, robot, joint)
        return tracker


def new_crossings(record: Alarm) -> list[dict[str, Any]]:
    """The detector crossings a published "raised"/"updated"/"chattering" record reports for the first
    time (those of its cycle): ``{"joint", "cycle", "quantity", "fault"}`` each (run statistics)."""
    if record.state not in ("raised", "updated", "chattering"):
        return []
    return [{"joint": record.joint, "cycle": record.cycle, "quantity": e["quantity"], "fault": record.fault}
            for e in record.detectors or () if e.get("cycle") == record.cycle]


__all__ = ["AlarmConfig", "CHATTER_CYCLES", "Fault", "FaultTracker", "new_crossings"]
