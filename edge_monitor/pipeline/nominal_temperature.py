"""The temperatures each detector's nominal was learned at, and the cycles a detector holds because
the joint is far from them (docs/DETECTION.md, "Operating conditions").

The temperature compensation of the KL distances is identified over a few °C; carried much further, it
leaves a drift a detector reads as a fault. Two cases meet every plant:

* **warming after commissioning or a maintenance** (the warm-up stage): the warm-up nominal is learned
  in the first cycles, cold; as the lubricant warms by ≈ 25 °C the KL distances of some joints drift up
  by more than the detectors' drift allowance (measured on 162 healthy joints: ≈ +0.035 σ per °C for
  kl_weighted, +0.02 σ per °C for kl_raw, with a joint-to-joint spread that grows as they warm; the wear
  score, compensated through the friction model, drifts down). So the warm-up detectors of the
  temperature-sensitive quantities (``decision.warm_up_hold``) skip the cycles warmer than the span
  they learned in, by more than the operating range's margin, until the steady stage replaces their
  nominal; the values a held detector would add to its steady nominal still go in. The wear evidence
  keeps watching throughout.
* **a restart after a stop**: a nominal learned warm describes the joint warm; after a long stop the
  lubricant is back near ambient, and a cold joint's KL distances sit well above it. So a steady
  detector skips the cycles colder than its span by more than the margin, until the joint is back in
  range; so does a warm-up detector of ``decision.warm_up_hold`` (a joint that stops before it settled:
  its warm-up nominal was learned in its first, already warming cycles; seed 401 of the plant week
  restarted 10 °C below them and raised a kl_raw false alarm).

:class:`NominalSpans` keeps, per detector, the span of the joint's temperature [°C] over the cycles
whose values went into its current nominal; both the spans and the holds read the temperature smoothed
over a few cycles (:mod:`~edge_monitor.pipeline.hold_temperature`: the per-cycle scatter would widen a
span by its extremes and make a hold flicker). Unknown temperature, or no span: no hold. A joint whose
controller sends no motor temperature is followed by the lubricant temperature its wear estimate reads from
the friction curve instead (:meth:`~edge_monitor.pipeline.joint_monitor.JointMonitor.joint_temperature`),
for both holds and its settling. Its price: wear reads as a slightly warmer lubricant (the two are estimated
together; +1.5 … 4 °C at wear 20 on a warm joint), so a worn joint's warm-up KL detectors hold a little
sooner; without the hold such a joint's warm-up KL detectors false-alarm in storms (docs/DETECTION.md,
"A robot without motor temperature"). The wear evidence never holds while the joint warms.
"""

from __future__ import annotations

from typing import Any, Collection

from edge_monitor.pipeline.operating_range import Span, is_span
from edge_monitor.stats.sequential_detector import SequentialDetector

#: The covariate whose span is kept (the operating range's name for it, and its margin).
COVARIATE = "motor_temperature"
#: What the joint's temperature is (named in the hold reasons): the controller's motor temperature, or, on a
#: joint whose controller sends none, the lubricant temperature the wear estimate reads from the friction.
MOTOR_TEMPERATURE, FRICTION_TEMPERATURE = "motor temperature", "lubricant temperature (from the friction)"


class NominalSpans:
    """Per quantity, the temperature span of its current nominal (``learned``) and of the one being
    collected (``collecting``); ``warm_up_hold`` names the quantities whose warm-up detectors hold while
    the joint is outside their span (warmer: only with ``warm_side``, by more than ``warm_margin``)."""

    def __init__(self, learned: dict[str, Span] | None = None, collecting: dict[str, Span] | None = None,
                 warm_up_hold: Collection[str] = (), warm_margin: float = 0.0, warm_side: bool = True) -> None:
        self.learned: dict[str, Span] = dict(learned or {})
        self.collecting: dict[str, Span] = dict(collecting or {})
        self.warm_up_hold = frozenset(warm_up_hold)
        self.warm_margin = float(warm_margin)      # the least margin [°C] above a warm-up span before it holds
        self.warm_side = warm_side                 # False without the steady stage: nothing would end that hold

    def held(self, quantity: str, detector: SequentialDetector, temperature: float | None,
             source: str = MOTOR_TEMPERATURE) -> str:
        """Why ``quantity``'s monitoring detector does not decide at ``temperature`` ("" if it does): a steady
        detector while the joint is colder than its span by more than the operating range's margin
        (max(2 °C, 10 % of the span)); a warm-up one of :attr:`warm_up_hold` while it is colder by that much,
        or warmer by more than :attr:`warm_margin` (at least that margin; only with :attr:`warm_side`).
        ``source``: what the temperature is (named in the reason)."""
        span = self.learned.get(quantity)
        if span is None or temperature is None or detector.state != "monitoring":
            return ""
        margin = span.margin(COVARIATE)
        if detector.stage == "steady" and temperature < span.lo - margin:
            return (f"held: {source} {temperature:.1f} °C (smoothed) below the {span.lo:.1f} … {span.hi:.1f} °C "
                    f"the steady nominal was learned in (warming again after a stop); monitoring resumes when it "
                    f"is back")
        if detector.stage == "steady" or quantity not in self.warm_up_hold:
            return ""
        if self.warm_side and temperature > span.hi + max(margin, self.warm_margin):
            return (f"held: {source} {temperature:.1f} °C (smoothed) above the {span.lo:.1f} … {span.hi:.1f} °C "
                    f"the warm-up nominal was learned in (the joint is warming); monitoring resumes on the steady "
                    f"nominal once the temperature has settled")
        if temperature < span.lo - margin:
            return (f"held: {source} {temperature:.1f} °C (smoothed) below the {span.lo:.1f} … {span.hi:.1f} °C "
                    f"the warm-up nominal was learned in (cold again after a stop); monitoring resumes when it is back")
        return ""

    def track(self, quantity: str, detector: SequentialDetector, collected: bool, fitted: bool,
              temperature: float | None) -> None:
        """After ``detector`` took a cycle: extend the span being collected by ``temperature`` if the cycle's
        value went into a nominal (``collected``); keep it as the learned span if that value completed the
        nominal (``fitted``: the detector fitted a new one), drop it if the collection ended otherwise (an
        alarm latched, or the joint warmed again): the current nominal's span stays."""
        if not collected:
            self.collecting.pop(quantity, None)
            return
        span = self.collecting.setdefault(quantity, Span())
        if temperature is not None:
            span.add(temperature)
        if fitted:
            span = self.collecting.pop(quantity)
            if span.empty:
                self.learned.pop(quantity, None)
            else:
                self.learned[quantity] = span
        elif not detector.collecting:
            self.collecting.pop(quantity, None)

    def forget(self, quantity: str) -> None:
        """``quantity``'s detector learns from scratch (its saved state was not usable): no span."""
        self.learned.pop(quantity, None)
        self.collecting.pop(quantity, None)

    def restart(self, quantity: str) -> None:
        """``quantity``'s detector starts collecting its nominal over (what it collected is dropped)."""
        self.collecting.pop(quantity, None)

    def clear(self) -> None:
        """A declared maintenance: every detector learns again."""
        self.learned.clear()
        self.collecting.clear()

    def state_dict(self) -> dict[str, Any]:
        """Non-empty spans only (strict JSON: an empty span is infinite)."""
        return {key: {q: [s.lo, s.hi] for q, s in spans.items() if not s.empty}
                for key, spans in (("learned", self.learned), ("collecting", self.collecting))}

    @classmethod
    def from_state(cls, state: Any, warm_up_hold: Collection[str] = (), warm_margin: float = 0.0,
                   warm_side: bool = True) -> "NominalSpans":
        """From :meth:`state_dict`; anything else (a state saved before spans were kept, a damaged span)
        is left out: no hold for that detector. (A state saved before 2026-11-27 holds only the steady
        nominals' spans; its warm-up detectors do not hold until they learn again.)"""
        saved: dict[str, Any] = state if isinstance(state, dict) else {}
        return cls(_spans(saved.get("learned")), _spans(saved.get("collecting")), warm_up_hold, warm_margin, warm_side)


def _spans(saved: Any) -> dict[str, Span]:
    """{quantity: span} from a saved {quantity: [lo, hi]}; what is not a span is left out."""
    items = saved.items() if isinstance(saved, dict) else ()
    return {str(q): Span(float(v[0]), float(v[1])) for q, v in items if is_span(v)}
