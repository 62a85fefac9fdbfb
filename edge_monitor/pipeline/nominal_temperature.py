"""The temperatures each detector's nominal was learned at, and what a detector does when the joint is far
from them (docs/DETECTION.md, "Watching while the joint warms").

The KL distances' temperature compensation (through the joint's friction model) leaves a drift that grows
with the distance from the temperatures a nominal was learned at: over the first few °C fast, then slowly
(on healthy default robots the largest joint's log kl_weighted drifted +0.7 σ at 3 °C and +1.5 σ at 17 °C
beyond its warm-up span; the median joint +0.2 and +0.4 σ). Two cases meet every plant: the warm-up after
commissioning or a maintenance (the warm-up nominal is learned cold, the joint then warms ≈ 25 °C), and a
restart after a stop (a nominal learned warm, a joint back near ambient).

:class:`NominalSpans` keeps, per detector, the span of the joint's temperature [°C] over the cycles whose
values went into its current nominal, and says how far a cycle lies outside it (:meth:`NominalSpans.distance`).
By default a detector then keeps testing with a **slack** (:meth:`NominalSpans.slack`): its value less
c·√d nominal standard deviations per input, d the distance, c from ``[decision.temperature_slack]`` (the
KL distances; the wear score, compensated through the model, gets none). A detector of a quantity listed in
``decision.warm_up_hold`` holds instead (:meth:`NominalSpans.held`, the earlier design: it tests nothing while
the joint is warmer, in the warm-up stage, or colder, in either stage, than its span).

Both the spans and the distance read the temperature smoothed over a few cycles
(:mod:`~edge_monitor.pipeline.hold_temperature`: the per-cycle scatter would widen a span by its extremes).
Unknown temperature, or no span: no slack and no hold. A joint whose controller sends no motor temperature
is followed by the lubricant temperature its wear estimate reads from the friction curve instead
(:meth:`~edge_monitor.pipeline.joint_monitor.JointMonitor.joint_temperature`): wear reads as a slightly warmer
lubricant (+1.5 … 4 °C at wear 20 on a warm joint), which adds a little slack (0.27·(√(d + 4) − √d) σ, 0.13 σ
at d = 16 °C) — far less than a hold, which such a joint's wear used to trip for good.
"""

from __future__ import annotations

import math
from typing import Any, Collection, Mapping, Sequence

import numpy as np

from edge_monitor.pipeline.operating_range import Span, is_span
from edge_monitor.pipeline.temperature_slack import SlackProfile, prior_for, standardized
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
                 warm_up_hold: Collection[str] = (), warm_margin: float = 0.0, warm_side: bool = True,
                 slack_prior: Mapping[str, tuple[float, float]] | None = None) -> None:
        self.learned: dict[str, Span] = dict(learned or {})
        self.collecting: dict[str, Span] = dict(collecting or {})
        self.slack_prior = dict(slack_prior or {})      # per detector input: the fleet's law (mean, sd) [σ/√°C]
        self.profiles: dict[str, SlackProfile] = {}     # per quantity: its joint's law, learned (:meth:`learn`)
        self.origins: dict[str, float] = {}             # per steady quantity: its warm-up span's top [°C]
        self.warm_up_hold = frozenset(warm_up_hold)
        self.warm_margin = float(warm_margin)      # the least margin [°C] above a warm-up span before it holds
        self.warm_side = warm_side                 # False without the steady stage: nothing would end that hold

    def held(self, quantity: str, detector: SequentialDetector, temperature: float | None,
             source: str = MOTOR_TEMPERATURE) -> str:
        """Why ``quantity``'s monitoring detector does not decide at ``temperature`` ("" if it does), for the
        quantities of :attr:`warm_up_hold` only (the others test with the temperature slack, :meth:`slack`): a
        steady detector while the joint is colder than its span by more than the operating range's margin
        (max(2 °C, 10 % of the span)); a warm-up one while it is colder by that much, or warmer by more than
        :attr:`warm_margin` (at least that margin; only with :attr:`warm_side`). ``source``: what the
        temperature is (named in the reason)."""
        span = self.learned.get(quantity)
        if span is None or temperature is None or detector.state != "monitoring" or quantity not in self.warm_up_hold:
            return ""
        margin = span.margin(COVARIATE)
        if detector.stage == "steady" and temperature < span.lo - margin:
            return (f"held: {source} {temperature:.1f} °C (smoothed) below the {span.lo:.1f} … {span.hi:.1f} °C "
                    f"the steady nominal was learned in (warming again after a stop); monitoring resumes when it "
                    f"is back")
        if detector.stage == "steady":
            return ""
        if self.warm_side and temperature > span.hi + max(margin, self.warm_margin):
            return (f"held: {source} {temperature:.1f} °C (smoothed) above the {span.lo:.1f} … {span.hi:.1f} °C "
                    f"the warm-up nominal was learned in (the joint is warming); monitoring resumes on the steady "
                    f"nominal once the temperature has settled")
        if temperature < span.lo - margin:
            return (f"held: {source} {temperature:.1f} °C (smoothed) below the {span.lo:.1f} … {span.hi:.1f} °C "
                    f"the warm-up nominal was learned in (cold again after a stop); monitoring resumes when it is back")
        return ""

    def outside(self, quantity: str, detector: SequentialDetector, temperature: float | None) -> tuple[str, float]:
        """Which side of the span ``quantity``'s monitoring nominal was learned in ``temperature`` lies on
        ("warm" or "cold"), and how far [°C] (0.0 inside it, with no span, no temperature, or while the
        detector learns)."""
        span = self.learned.get(quantity)
        if span is None or span.empty or temperature is None or detector.state != "monitoring":
            return "warm", 0.0
        if temperature > span.hi:
            return "warm", temperature - span.hi
        return "cold", max(0.0, span.lo - temperature)

    def regressor(self, quantity: str, detector: SequentialDetector, temperature: float | None) -> tuple[str, float]:
        """The side and the regressor x [√°C] of ``quantity``'s temperature law at ``temperature``
        (:mod:`~edge_monitor.pipeline.temperature_slack`): √d outside its nominal's span; on the warm side of a
        steady nominal whose joint's warm-up span is known (:attr:`origins`), √(T − o) − √(hi − o), o that span's
        top and hi the steady span's (0.0 inside, with no span or temperature, or while the detector learns)."""
        side, d = self.outside(quantity, detector, temperature)
        origin = self.origins.get(quantity)
        if d <= 0 or side == "cold" or origin is None or detector.stage != "steady" or temperature is None:
            return side, math.sqrt(d)
        top = self.learned[quantity].hi
        return side, math.sqrt(max(0.0, temperature - origin)) - math.sqrt(max(0.0, top - origin))

    def slack(self, quantity: str, inputs: Sequence[str], detector: SequentialDetector,
              temperature: float | None) -> tuple[float, ...] | None:
        """The drift [nominal standard deviations] ``quantity``'s ``inputs`` may show at ``temperature``
        beyond what its detector learned (:class:`~edge_monitor.pipeline.temperature_slack.SlackProfile`: the
        joint's own law, learned from the fleet's); the detector tests the value less it. None when there is
        none (inside the span, no temperature, no law)."""
        side, x = self.regressor(quantity, detector, temperature)
        return self._profile(quantity, inputs).slack(side, x) if x > 0 else None

    def learn(self, quantity: str, inputs: Sequence[str], detector: SequentialDetector, value: Sequence[float],
              temperature: float | None) -> None:
        """A cycle ``quantity``'s detector tested (no alarm latched) at ``temperature``: its value, in standard
        deviations of the nominal, teaches the joint's law of that side (inside the span: nothing)."""
        side, x = self.regressor(quantity, detector, temperature)
        density = detector.density
        if x <= 0 or density is None or detector.alarmed:
            return
        vec = np.asarray(value, dtype=float).ravel()
        vec = vec if detector.transform is None else detector.transform.apply(vec)
        self._profile(quantity, inputs).update(side, x, standardized(vec, density.mean, density.spread))

    def _profile(self, quantity: str, inputs: Sequence[str]) -> SlackProfile:
        if quantity not in self.profiles:
            self.profiles[quantity] = SlackProfile(prior_for(inputs, self.slack_prior))
        return self.profiles[quantity]

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
            self._new_nominal(quantity, detector)
            span = self.collecting.pop(quantity)
            if span.empty:
                self.learned.pop(quantity, None)
            else:
                self.learned[quantity] = span
        elif not detector.collecting:
            self.collecting.pop(quantity, None)

    def _new_nominal(self, quantity: str, detector: SequentialDetector) -> None:
        """``quantity``'s detector fitted a new nominal: a steady one after a warm-up one keeps the warm-up's law
        (its warm side re-anchored at the warm-up span's top, :meth:`regressor`); any other starts from the
        prior (a maintenance, a relearn)."""
        warm_up = self.learned.get(quantity)
        if detector.stage == "steady" and warm_up is not None and not warm_up.empty and quantity not in self.origins:
            self.origins[quantity] = warm_up.hi
            return
        self.profiles.pop(quantity, None)
        self.origins.pop(quantity, None)

    def forget(self, quantity: str) -> None:
        """``quantity``'s detector learns from scratch (its saved state was not usable): no span."""
        self.learned.pop(quantity, None)
        self.collecting.pop(quantity, None)
        self.profiles.pop(quantity, None)
        self.origins.pop(quantity, None)

    def restart(self, quantity: str) -> None:
        """``quantity``'s detector starts collecting its nominal over (what it collected is dropped)."""
        self.collecting.pop(quantity, None)

    def clear(self) -> None:
        """A declared maintenance: every detector learns again."""
        self.learned.clear()
        self.collecting.clear()
        self.profiles.clear()
        self.origins.clear()

    def state_dict(self) -> dict[str, Any]:
        """Non-empty spans only (strict JSON: an empty span is infinite), and the learned laws."""
        out: dict[str, Any] = {key: {q: [s.lo, s.hi] for q, s in spans.items() if not s.empty}
                               for key, spans in (("learned", self.learned), ("collecting", self.collecting))}
        out["profiles"] = {q: p.state_dict() for q, p in self.profiles.items()}
        out["origins"] = dict(self.origins)
        return out

    @classmethod
    def from_state(cls, state: Any, warm_up_hold: Collection[str] = (), warm_margin: float = 0.0,
                   warm_side: bool = True, slack_prior: Mapping[str, tuple[float, float]] | None = None,
                   inputs: Mapping[str, Sequence[str]] | None = None) -> "NominalSpans":
        """From :meth:`state_dict`; anything else (a state saved before spans were kept, a damaged span)
        is left out: no hold for that detector. (A state saved before 2026-11-27 holds only the steady
        nominals' spans; its warm-up detectors do not hold until they learn again.)"""
        saved: dict[str, Any] = state if isinstance(state, dict) else {}
        out = cls(_spans(saved.get("learned")), _spans(saved.get("collecting")), warm_up_hold, warm_margin, warm_side,
                  slack_prior)
        profiles: dict[str, Any] = saved["profiles"] if isinstance(saved.get("profiles"), dict) else {}
        for quantity, names in (inputs or {}).items():
            if quantity in profiles and quantity in out.learned:
                out.profiles[quantity] = SlackProfile.from_state(prior_for(names, out.slack_prior), profiles[quantity])
        origins: dict[str, Any] = saved["origins"] if isinstance(saved.get("origins"), dict) else {}
        out.origins = {str(q): float(o) for q, o in origins.items()
                       if q in out.profiles and isinstance(o, (int, float)) and math.isfinite(o)}
        return out


def _spans(saved: Any) -> dict[str, Span]:
    """{quantity: span} from a saved {quantity: [lo, hi]}; what is not a span is left out."""
    items = saved.items() if isinstance(saved, dict) else ()
    return {str(q): Span(float(v[0]), float(v[1])) for q, v in items if is_span(v)}
