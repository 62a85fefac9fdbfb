"""The motor temperatures a joint's steady nominals were learned at, and the cycles a steady detector
holds because the joint is colder (docs/DETECTION.md, "Operating conditions": a restart after a stop).

A steady nominal describes the joint warm. After a long stop the lubricant is back near ambient, far
below the temperatures of the cycles that nominal was learned from, and the temperature compensation
of the quantities, identified over a few °C, does not carry them that far: a cold joint's KL distances
sit well above a warm nominal. So, per detector, :class:`SteadySpans` keeps the span of the cycle-mean
motor temperature [°C] over the cycles whose values went into its steady nominal, and a steady detector
skips the cycles colder than that span by more than the operating range's margin until the joint is
back in range. Unknown temperature, or no span: no hold.
"""

from __future__ import annotations

from typing import Any

from edge_monitor.pipeline.operating_range import Span, is_span
from edge_monitor.stats.sequential_detector import SequentialDetector

#: The covariate whose span is kept (the operating range's name for it, and its margin).
COVARIATE = "motor_temperature"


class SteadySpans:
    """Per quantity, the motor-temperature span of its steady nominal (``learned``) and of the one being
    collected (``collecting``)."""

    def __init__(self, learned: dict[str, Span] | None = None, collecting: dict[str, Span] | None = None) -> None:
        self.learned: dict[str, Span] = dict(learned or {})
        self.collecting: dict[str, Span] = dict(collecting or {})

    def held(self, quantity: str, detector: SequentialDetector, temperature: float | None) -> str:
        """Why ``quantity``'s detector skips a cycle at ``temperature`` ("" if it does not): it is steady,
        not collecting, and the joint is colder than its steady span by more than the operating range's
        margin (max(2 °C, 10 % of the span))."""
        span = self.learned.get(quantity)
        if span is None or temperature is None or detector.stage != "steady" or detector.collecting:
            return ""
        if temperature >= span.lo - span.margin(COVARIATE):
            return ""
        return (f"held: motor temperature {temperature:.1f} °C below the {span.lo:.1f} … {span.hi:.1f} °C the "
                f"steady nominal was learned in (warming again after a stop); monitoring resumes when it is back")

    def track(self, quantity: str, detector: SequentialDetector, collected: bool, temperature: float | None) -> None:
        """After ``detector`` took a cycle: extend the span being collected by ``temperature`` if the cycle's
        value went into the steady nominal (``collected``); keep it once that nominal is fitted, drop it
        if the collection was dropped."""
        if not collected:
            self.collecting.pop(quantity, None)
            return
        span = self.collecting.setdefault(quantity, Span())
        if temperature is not None:
            span.add(temperature)
        if not detector.collecting_steady:                  # this value completed the steady nominal
            fitted = self.collecting.pop(quantity)
            if detector.stage == "steady" and not detector.collecting and not fitted.empty:
                self.learned[quantity] = fitted

    def clear(self) -> None:
        """A declared maintenance: every detector learns again."""
        self.learned.clear()
        self.collecting.clear()

    def state_dict(self) -> dict[str, Any]:
        """Non-empty spans only (strict JSON: an empty span is infinite)."""
        return {key: {q: [s.lo, s.hi] for q, s in spans.items() if not s.empty}
                for key, spans in (("learned", self.learned), ("collecting", self.collecting))}

    @classmethod
    def from_state(cls, state: Any) -> "SteadySpans":
        """From :meth:`state_dict`; anything else (a state saved before spans were kept, a damaged span)
        is left out: no hold for that detector."""
        saved: dict[str, Any] = state if isinstance(state, dict) else {}
        return cls(_spans(saved.get("learned")), _spans(saved.get("collecting")))


def _spans(saved: Any) -> dict[str, Span]:
    """{quantity: span} from a saved {quantity: [lo, hi]}; what is not a span is left out."""
    items = saved.items() if isinstance(saved, dict) else ()
    return {str(q): Span(float(v[0]), float(v[1])) for q, v in items if is_span(v)}
