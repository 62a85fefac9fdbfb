"""What a fleet study counts of the detectors' decisions and alarms: per joint and quantity the monitored
cycles (the exposure), per stage; the false alarms of healthy joints and the run length they imply; the
first alarm of each worn joint; and the reported miss probability against the observed misses
(docs/DETECTION.md, "Healthy robot", "Miss probability against observed misses"). A run record is the dict
:func:`studies.robots.run_robot` returns.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any


@dataclass
class DecisionTally:
    """What a study keeps of the decisions, per joint and quantity: the monitored cycles, the first cycle
    of the steady stage and the reported miss probability per cycle (until the alarm)."""

    monitored: dict[int, dict[str, int]] = field(default_factory=dict)
    monitored_steady: dict[int, dict[str, int]] = field(default_factory=dict)
    steady_from: dict[int, dict[str, int]] = field(default_factory=dict)
    miss: dict[int, dict[str, dict[int, float]]] = field(default_factory=dict)

    def add(self, joint: int, cycle: int, decisions: dict[str, Any]) -> None:
        for q, decision in decisions.items():
            steady = (decision.calibration or {}).get("stage") == "steady"
            if steady:
                self.steady_from.setdefault(joint, {}).setdefault(q, cycle)
            if decision.state == "monitoring" and decision.threshold is not None and decision.statistic is not None:
                for tally in (self.monitored, self.monitored_steady) if steady else (self.monitored,):
                    counts = tally.setdefault(joint, {})
                    counts[q] = counts.get(q, 0) + 1
                if decision.miss_probability is not None and not decision.alarm:
                    self.miss.setdefault(joint, {}).setdefault(q, {})[cycle] = decision.miss_probability

    def fields(self, worn: list[int]) -> dict[str, Any]:
        """The run record's ``monitored``, ``steady_from`` and ``miss_probability`` (worn joints only)."""
        return {"monitored": {str(j): c for j, c in self.monitored.items()},
                "monitored_steady": {str(j): c for j, c in self.monitored_steady.items()},
                "steady_from": {str(j): c for j, c in self.steady_from.items()},
                "miss_probability": {str(j): {q: {str(c): p for c, p in per.items()}
                                              for q, per in self.miss.get(j, {}).items()} for j in worn}}


def earliest_alarm(run: dict[str, Any], joint: int, quantity: str | None = None) -> dict[str, Any] | None:
    """The first alarm of ``joint`` in ``run`` (of ``quantity`` only, if given), or None."""
    mine = [a for a in run["alarms"] if a["joint"] == joint and quantity in (None, a["quantity"])]
    return min(mine, key=lambda a: a["cycle"]) if mine else None


def summarise(runs: list[dict[str, Any]]) -> dict[str, Any]:
    """Pooled over robots: false alarms and exposure per quantity on unworn joints, first alarms of worn ones."""
    exposure: dict[str, int] = {}
    false_alarms: dict[str, int] = {}
    steady_exposure: dict[str, int] = {}
    steady_alarms: dict[str, int] = {}
    detections = []
    for run in runs:
        worn = set(run["worn"])
        for tally, key in ((exposure, "monitored"), (steady_exposure, "monitored_steady")):
            for joint, counts in run.get(key, {}).items():
                if int(joint) in worn:
                    continue
                for q, n in counts.items():
                    tally[q] = tally.get(q, 0) + n
        for alarm in run["alarms"]:
            if alarm["joint"] in worn:
                continue
            false_alarms[alarm["quantity"]] = false_alarms.get(alarm["quantity"], 0) + 1
            if alarm.get("stage") == "steady":
                steady_alarms[alarm["quantity"]] = steady_alarms.get(alarm["quantity"], 0) + 1
        for joint in worn:
            detections.append({"seed": run["seed"], "joint": joint, "first_alarm": earliest_alarm(run, joint)})
    per_quantity = {}
    for q, n in sorted(exposure.items()):
        k = false_alarms.get(q, 0)
        # with no alarm, the 95 % one-sided Poisson bound: rate ≤ 3/exposure
        per_quantity[q] = {"exposure": n, "false_alarms": k,
                           "arl0": n / k if k else None, "arl0_95_lower": n / 3.0 if not k else None,
                           "steady_exposure": steady_exposure.get(q, 0), "steady_false_alarms": steady_alarms.get(q, 0)}
    return {"per_quantity": per_quantity, "detections": detections,
            "false_alarms": sum(false_alarms.values()), "miss_forecast": miss_forecast(runs)}


def miss_forecast(runs: list[dict[str, Any]], every: int = 5) -> dict[str, list[dict[str, float]]]:
    """Per quantity and every ``every`` cycles over the worn joints: the fraction not alarmed yet (the
    observed miss frequency) next to the mean reported miss probability (an alarmed joint counts 0),
    and the mean true wear (docs/DETECTION.md, "Miss probability against observed misses")."""
    out: dict[str, list[dict[str, float]]] = {}
    worn = [(run, j) for run in runs for j in run["worn"]]
    if not worn:
        return out
    cycles = len(next(iter(worn[0][0]["wear_truth"].values())))
    quantities = sorted({a["quantity"] for run, _ in worn for a in run["alarms"]})
    for q in quantities:
        first = [alarm["cycle"] if (alarm := earliest_alarm(run, j, q)) else math.inf for run, j in worn]
        rows = []
        for cycle in range(0, cycles, every):
            missed, reported, wear = 0, 0.0, 0.0
            for (run, j), first_alarm in zip(worn, first):
                if cycle < first_alarm:
                    missed += 1
                    reported += run["miss_probability"].get(str(j), {}).get(q, {}).get(str(cycle), 1.0)
                wear += run["wear_truth"][str(j)][cycle]
            n = len(worn)
            rows.append({"cycle": cycle, "wear": wear / n, "observed_miss": missed / n, "mean_pm": reported / n})
        out[q] = rows
    return out
