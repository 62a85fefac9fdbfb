"""What an agent counts over a run: cycles, symptoms, alarms, faults and the records it could not deliver
(the health record and the run summary carry them, docs/OUTPUTS.md)."""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from typing import Any


@dataclass
class RunStats:
    cycles: int = 0
    symptoms: int = 0
    alarms: list[dict[str, Any]] = field(default_factory=list)   # detector crossings, each with its fault
    faults: int = 0                   # faults raised (one alarm per fault)
    chattering: int = 0               # crossings soon after an acknowledgement (the same fault, again)
    advisories: int = 0
    duplicate_cycles_skipped: int = 0
    partial_cycles: int = 0
    sink_errors: int = 0
    states_rejected: int = 0          # saved state files moved aside (unusable), relearned from scratch
    joint_states_rejected: int = 0    # joints whose saved models did not load, relearned alone
    acknowledged: int = 0             # alarms acknowledged by an operator (judged false)
    started: float = field(default_factory=time.perf_counter)
