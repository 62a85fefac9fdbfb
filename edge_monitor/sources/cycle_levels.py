"""The designed test-cycle levels as a capture shows them: what ``[cycles] speeds`` should say
(``edge-monitor check-mapping``, docs/CONNECTING.md).

A plateau detector without configured speeds finds the steady runs of the reference joint. Consecutive
plateaus at one level are one *visit*. A level of the test cycle is visited once per cycle, one plateau
per direction (+v, then −v); a speed the robot holds more often, several times per visit in one
direction, or in one direction only, is the production motion's and is left out. The levels are listed
in the order of the cycle: the order of their first visits, begun at the level that follows the longest
typical pause (the production motion and the cycle's end lie before the first level).
"""

from __future__ import annotations

from collections import Counter
from dataclasses import dataclass, field
from statistics import median

from edge_monitor.features.segmentation import PlateauStat

#: Visits kept (a few hundred cycles of 12 levels and their production moves).
MAX_VISITS = 10_000


@dataclass
class _Visit:
    level: int
    start: int
    end: int
    directions: list[int] = field(default_factory=list)


@dataclass
class LevelSuggestion:
    """Levels of the test cycle in its order [rad/s], and the steady speeds left out as production."""

    speeds: list[float]
    production: list[float]


class CycleLevels:
    """Collects the plateaus of one joint (see the module docstring)."""

    def __init__(self) -> None:
        self.visits: list[_Visit] = []
        self._speed: dict[int, float] = {}

    def add(self, plateaus: list[PlateauStat]) -> None:
        for p in plateaus:
            self._speed[p.level] = abs(p.speed_mean)
            last = self.visits[-1] if self.visits else None
            if last is not None and last.level == p.level:
                last.end = p.tick_end
                last.directions.append(p.direction)
            else:
                self.visits.append(_Visit(p.level, p.tick_start, p.tick_end, [p.direction]))
        del self.visits[:-MAX_VISITS]

    def _production(self) -> set[int]:
        """Levels visited more often than the typical level, with a direction repeated within a visit, or
        mostly in one direction only (a test level is held +v, then −v)."""
        counts = Counter(v.level for v in self.visits)
        if not counts:
            return set()
        frequency = Counter(counts.values())
        typical = min(c for c, k in frequency.items() if k == max(frequency.values()))
        repeated = {v.level for v in self.visits if len(v.directions) != len(set(v.directions))}
        both = Counter(v.level for v in self.visits if set(v.directions) == {1, -1})
        one_way = {level for level, c in counts.items() if both[level] < c / 2}
        return {level for level, c in counts.items() if c > 1.5 * typical} | repeated | one_way

    def suggestion(self) -> LevelSuggestion:
        production = self._production()
        visits = [v for v in self.visits if v.level not in production]
        order = list(dict.fromkeys(v.level for v in visits))
        if len(order) > 1:
            pauses: dict[int, list[int]] = {}
            for before, visit in zip(visits, visits[1:]):
                pauses.setdefault(visit.level, []).append(visit.start - before.end)
            first = max(order, key=lambda level: median(pauses.get(level, [0])))
            order = order[order.index(first):] + order[:order.index(first)]
        return LevelSuggestion([round(self._speed[level], 2) for level in order],
                               sorted(round(self._speed[level], 2) for level in production))
