"""What healthy data do after a detector has learned its nominal, as the calibration assumes it: the
``[decision.healthy_drift]``, ``[decision.warm_up_law]``, ``[decision.warm_up_law_friction]``,
``[decision.steady_drift]``, ``[decision.steady_wander]``, ``[decision.temperature_slack]`` and
``[decision.learned_sd_prior_friction]`` tables, their
shipped values (measured on the simulator's healthy default robots, docs/DETECTION.md) and their
validation (a :class:`~edge_monitor.errors.ConfigError` naming the key)."""

from __future__ import annotations

from collections.abc import Callable, Mapping
from typing import Any, TypeVar

from edge_monitor.errors import ConfigError, require, shown
from edge_monitor.records import is_finite_number
from edge_monitor.stats.calibration import MAX_DRIFT, MAX_SKEW

#: Healthy drift of each detector input in the warm-up stage, beyond what the temperature slack takes
#: (:mod:`~edge_monitor.pipeline.temperature_slack`): (mean, sd) over joints of the value tested less its slack,
#: averaged over the cycles more than 5 °C outside the nominal's span, in standard deviations of the learned
#: values, in the units the detector watches. Measured on 19 healthy default robots (seeds 7001–7006 and
#: 8201–8213, 114 joints, ``tools/studies/temperature_law_study.py``, the agent with the measured load and the
#: slack prior below: wear score +0.05 ± 0.26 (the two groups −0.03 ± 0.25 and +0.09 ± 0.26), log kl_raw
#: −0.13 ± 0.071 / ± 0.056, log kl_weighted −0.13 / −0.12 ± 0.05; the KL distances sit below their nominal by
#: the slack's margin, their means are rounded up to 0 and their spreads to 0.08; docs/DETECTION.md, "Watching
#: while the joint warms"). Before the measured load (36 joints): wear score −0.02 ± 0.31,
#: KL −0.12 ± 0.085 and ± 0.06; without the slack (before it) wear score (0.05, 0.41), log kl_raw (0.30, 0.23),
#: log kl_weighted (0.28, 0.17).
HEALTHY_DRIFT: dict[str, tuple[float, float]] = {"wear_score": (0.05, 0.26), "kl_raw": (0.0, 0.08),
                                                  "kl_weighted": (0.0, 0.08)}
#: What a healthy joint's scalar warm-up detector tests, in the units its nominal learned (mean 0, sd 1 of its
#: learning values), as a law over joints: (mean, sd) of each joint's mean and (mean, sd) of each joint's
#: spread [learned standard deviations], of its value less its temperature slack over every warm-up cycle it
#: tests. Measured there, the law holds the nominal's learning error, so the calibration draws it instead of
#: the learning error and [decision.healthy_drift] (which the joint vector keeps). The KL distances' values
#: after learning are steadier than the ones they were learned from and the slack keeps their joints' means
#: together: on 13 healthy robots (seeds 7001–7002 and the plant weeks 401–407, 7101–7104, their first 1 200
#: cycles; 78 joints, ``tools/studies/temperature_law_study.py``) log kl_raw's means −0.141 ± 0.071 and spreads
#: 0.975 ± 0.105, log kl_weighted's −0.126 ± 0.047 and 0.908 ± 0.084, where the learning error and
#: [decision.healthy_drift] assumed means 0 ± 0.15 and spreads 1.01 ± 0.09 (docs/DETECTION.md, "The warm-up
#: stage"). The wear score's joints differ in their spread as well as in their mean: means +0.061 ± 0.261,
#: spreads 1.068 ± 0.211, where the learning error gives the spreads 1.01 ± 0.09.
#: The fifth number: the fraction of the values' variance in a slow AR(1) wander (coefficient 0.7), as
#: ``STEADY_WANDER``; the KL distances' warm-up values wander too (k·var(k-mean)/var ≈ 1.16–1.18 at k = 10 and
#: 1.27–1.37 at k = 30; 0.09 gives 1.28 and 1.38): without it two held-out robots of 26 raised a KL false alarm
#: at the default budget where 0.18 were due (docs/DETECTION.md, "The warm-up stage").
#: The sixth: the skew-normal shape α of the values' iid part (0: Gaussian), an option. log kl_raw's values put 1.4 %
#: above 2 of a joint's own sd where a Gaussian puts 2.3 %, and 0.22 % above 2.5 sd; α = −1.76 fits both (the same
#: tool, ``tail_shape``) and made kl_raw deliver its stated rate at short targets, but at the default budget it
#: raised a false alarm on a held-out robot where 0.05 were due, and another on 40 more robots where 0.07 were due
#: (the far tail measured is as light as the shape says; docs/DETECTION.md, "The warm-up stage"). So the shipped
#: shapes are 0.
WARM_UP_LAW: dict[str, tuple[float, float, float, float, float, float]] = {
    "wear_score": (0.061, 0.261, 1.068, 0.211, 0.0, 0.0), "kl_raw": (-0.141, 0.071, 0.975, 0.105, 0.09, 0.0),
    "kl_weighted": (-0.126, 0.047, 0.908, 0.084, 0.09, 0.0)}
#: The warm-up law of a joint whose controller sends no motor temperature, per input where it differs from
#: :data:`WARM_UP_LAW` (``[decision.warm_up_law_friction]``). Its detectors follow the lubricant temperature its wear
#: estimate reads from the friction, and that estimate, free to trade temperature for wear cycle by cycle, makes the
#: wear score spread wider with a heavier upper tail, and its joints' means differ more. Measured as WARM_UP_LAW
#: (``temperature_law_study.py --no-motor-temperature --seeds 7341-7360``, 20 healthy default robots without motor
#: temperature, 120 joints), with the learned sd's prior below (LEARNED_SD_PRIOR_FRICTION): means −0.011 ± 0.243,
#: spreads 1.090 ± 0.183, 2.9 % of the values above 2 of a joint's own sd and 0.95 % above 2.5; the skew-normal shape
#: +1.28 fits the first and predicts the second (1.01 %). Without the prior (2026-11-30): +0.001 ± 0.285, 1.244 ±
#: 0.225, the same shape (docs/WITHOUT_MOTOR_TEMPERATURE.md). The joint vector of such a
#: joint draws its wear axis from this law too and its KL axes from WARM_UP_LAW's (2026-12-01; with their learning
#: error and healthy drift instead it ran 1.57–1.74× quiet at short targets). The KL distances' laws lie within
#: their sds of WARM_UP_LAW's. An earlier measurement on 10 other robots (7001–7006, plant weeks 401–404;
#: means −0.075 ± 0.238, spreads 1.184 ± 0.231, shape +1.41) put the joints' means closer together than these 120
#: joints do, which lowered the long targets' thresholds: not shipped.
WARM_UP_LAW_FRICTION: dict[str, tuple[float, float, float, float, float, float]] = {
    "wear_score": (-0.011, 0.243, 1.090, 0.183, 0.0, 1.28)}
#: On such a joint, the warm-up nominal's learned sd of each input listed, shrunk towards the input's own sd by k
#: pseudo-values (``[decision.learned_sd_prior_friction]``, input → (k, sd); densities.with_sd_prior). The wear
#: score is the signed root of a likelihood ratio, ≈ N(0, 1) on a healthy joint; without motor temperature its
#: cold learning window scatters less (learned sd: median 0.71, 5 % below 0.44; 0.87 and 0.57 with one), and a
#: joint learned that calm spreads wider in its learned units: the false alarms at the default budget fell on
#: such joints (7345 joint 0, 7369 joint 4: learned sds 0.53 and 0.30). On the 120 joints of seeds 7341–7360,
#: k = 20 gave the smallest spread of log(warm-up sd / learned sd) of k = 20, 60, 120 and floors 0.5 … 0.9
#: (0.171, as learned 0.179) and their largest ratio 1.54 (as learned 1.91): learned_spread_study.py.
LEARNED_SD_PRIOR_FRICTION: dict[str, tuple[float, float]] = {"wear_score": (20.0, 1.0)}
#: The same once warm, for the scalar detectors: (mean, sd) over joints and operating periods of how far each
#: input sits, after its steady nominal is learned, from that nominal (in its learned standard deviations,
#: beyond the learning error the calibration simulates itself). Measured on a plant's ordinary week (the
#: plant-week scenario, seeds 401–407: shifts, stops, a product change, a hot day; per joint the means
#: before the product change, over it, over the hot day and after, weighted by their cycles; docs/DETECTION.md,
#: "The steady stage on a plant's week", ``tools/studies/plant_drift_study.py``): kl_weighted follows the cycle's load
#: after compensation and the hot day. kl_weighted is measured with the measured load (seeds 401–404, 24 joints:
#: (+0.066, 0.159); its period means −0.15, +0.11, +0.31 and +0.12 σ); before the measured load it was (0.18, 0.195).
#: kl_raw keeps its value from before the measured load (now measured (−0.03, 0.05): not yet changed, it is
#: the steady detector closest to its stated rate on plant weeks); the wear score does not move.
#: (Healthy default robots at one load range alone: kl_raw and kl_weighted (0.04, 0.03).) The wear score's
#: spread is a margin, like the joint vector's below: its period means drift 0.08 σ, but its values' tails are
#: heavier than the Gaussian's after the transform (excess kurtosis ≈ +0.5), and calibrated for 0.08 its
#: steady detector delivered 1.5×, 1.8× and 2.6× the stated rate at 10³, 3·10³ and 10⁴ on four plant weeks;
#: for 0.22, 0.97×, 1.03× and 0.68× (``tools/studies/delivered_curve.py --variant``, docs/DETECTION.md).
STEADY_DRIFT: dict[str, tuple[float, float]] = {"wear_score": (0.0, 0.22), "kl_raw": (0.05, 0.11),
                                                "kl_weighted": (0.07, 0.16)}
#: The drift the joint vector's steady calibration assumes of its inputs: larger than its inputs show
#: alone, because the three are not jointly Gaussian in their tails (the delivered curve of
#: docs/studies/2026-11-27-delivered-curve.md: with the inputs' own default-robot drift it ran ≈ 1.5×): the plant week's
#: drift of each KL input plus the margin that made the vector deliver on default robots (mean + 0.06 σ,
#: sd combined with 0.085 σ).
STEADY_DRIFT_JOINT: dict[str, tuple[float, float]] = {"wear_score": (0.0, 0.08), "kl_raw": (0.11, 0.14),
                                                      "kl_weighted": (0.24, 0.21)}
#: And how they wander once warm: the fraction of each input's variance in a slow AR(1) component
#: (coefficient 0.7, :data:`~edge_monitor.stats.gaussian_fleet.WANDER_COEFFICIENT`), from the
#: variance ratios of k-cycle means of the same joints: the log KL distances 1.19, 1.32, 1.39 at k = 5,
#: 10, 30 (iid: 1), the wear score ≤ 1 (docs/DETECTION.md, "The steady stage's healthy drift").
STEADY_WANDER: dict[str, float] = {"wear_score": 0.0, "kl_raw": 0.09, "kl_weighted": 0.09}
#: The fleet's law of how far a healthy joint's inputs drift while its temperature is d °C outside the span
#: their nominal was learned in: z = a·√d standard deviations of the learned values, a ~ N(mean, sd) over
#: joints [σ/√°C] — the prior each detector starts from and learns its own joint's a with
#: (:mod:`~edge_monitor.pipeline.temperature_slack`). Measured on healthy default robots (seeds 7001–7006, 36
#: joints, warm-up, the agent with the measured load: log kl_raw a = 0.070 ± 0.089, log kl_weighted 0.130 ±
#: 0.089, the steepest 0.37 and 0.43; before the measured load 0.094 ± 0.123 and 0.161 ± 0.125, up to 0.62 and
#: 0.66; docs/DETECTION.md, "Watching while the joint warms"). The wear score is compensated through the
#: friction model (a = −0.009 ± 0.070) and gets no slack: learning it would let slow wear into its law.
TEMPERATURE_SLACK: dict[str, tuple[float, float]] = {"wear_score": (0.0, 0.0), "kl_raw": (0.07, 0.09),
                                                     "kl_weighted": (0.13, 0.09)}
#: Largest slack law a config may state [σ/√°C] (at 25 °C: 15 σ, nothing would alarm beyond it).
MAX_SLACK = 3.0


T = TypeVar("T")


def _per_input(given: Any, key: str, defaults: Mapping[str, T], parse: Callable[[Any], T | None],
               expected: str) -> dict[str, T]:
    """``decision.<key>``: the defaults, overridden per detector input by ``given`` (input → value), each
    value read by ``parse`` (None: not valid, a ConfigError saying ``expected``)."""
    require(isinstance(given, Mapping), f"decision.{key}", f"expected a table, got {given!r}")
    out = dict(defaults)
    for name, value in given.items():
        require(name in defaults, f"decision.{key}.{name}", f"unknown input; known: {sorted(defaults)}")
        parsed = parse(value)
        if parsed is None:
            raise ConfigError(f"decision.{key}.{name}: expected {expected}, got {shown(value)}")
        out[name] = parsed
    return out


def _drift_pair(pair: Any) -> tuple[float, float] | None:
    ok = isinstance(pair, (list, tuple)) and len(pair) == 2 and all(is_finite_number(v) for v in pair)
    return (float(pair[0]), float(pair[1])) if ok and -MAX_DRIFT <= pair[0] <= MAX_DRIFT \
        and 0 <= pair[1] <= MAX_DRIFT else None


def healthy_drift(given: Any, key: str = "healthy_drift",
                   defaults: Mapping[str, tuple[float, float]] = HEALTHY_DRIFT) -> dict[str, tuple[float, float]]:
    """``decision.healthy_drift`` (or ``key``): input → [mean, sd] [σ]."""
    return _per_input(given, key, defaults, _drift_pair, f"[mean, sd] in standard deviations (mean "
                      f"−{MAX_DRIFT:g} … {MAX_DRIFT:g}, sd 0 … {MAX_DRIFT:g})")


def warm_up_law(given: Any, key: str = "warm_up_law",
                defaults: Mapping[str, tuple[float, ...]] = WARM_UP_LAW) -> dict[str, tuple[float, ...]]:
    """``decision.warm_up_law`` (or ``key``): input → [mean, sd, spread, spread sd] in learned standard deviations and
    optionally the wander's variance fraction and the skew-normal shape of the iid part (default 0 each); an empty
    list: none (``warm_up_law``: that input is left to ``[decision.healthy_drift]`` and the simulated learning error;
    ``warm_up_law_friction``: to ``warm_up_law``)."""
    def parse(law: Any) -> tuple[float, ...] | None:
        if isinstance(law, (list, tuple)) and len(law) == 0:
            return ()
        ok = isinstance(law, (list, tuple)) and len(law) in (4, 5, 6) and all(is_finite_number(v) for v in law)
        values = tuple(float(v) for v in law) + (0.0,) * (6 - len(law)) if ok else ()
        return values if ok and -MAX_DRIFT <= values[0] <= MAX_DRIFT and 0 <= values[1] <= MAX_DRIFT \
            and 0.05 <= values[2] <= 5 and 0 <= values[3] <= MAX_DRIFT and 0 <= values[4] < 1 \
            and abs(values[5]) <= MAX_SKEW else None
    parsed = _per_input(given, key, {**dict.fromkeys(HEALTHY_DRIFT, ()), **defaults}, parse,
                        f"[mean, sd, spread, spread sd(, wander(, skew))] in learned standard deviations (mean "
                        f"−{MAX_DRIFT:g} … {MAX_DRIFT:g}, sds 0 … {MAX_DRIFT:g}, spread 0.05 … 5, wander a variance "
                        f"fraction 0 … <1, skew a skew-normal shape −{MAX_SKEW:g} … {MAX_SKEW:g}), or [] for none")
    return {name: law for name, law in parsed.items() if law}


def temperature_slack(given: Any) -> dict[str, tuple[float, float]]:
    """``decision.temperature_slack``: input → the fleet's law [mean, sd] [σ/√°C]."""
    def parse(pair: Any) -> tuple[float, float] | None:
        ok = isinstance(pair, (list, tuple)) and len(pair) == 2 and all(is_finite_number(v) for v in pair)
        return (float(pair[0]), float(pair[1])) if ok and -MAX_SLACK <= pair[0] <= MAX_SLACK \
            and 0 <= pair[1] <= MAX_SLACK else None
    return _per_input(given, "temperature_slack", TEMPERATURE_SLACK, parse,
                      f"[mean, sd] of the law in standard deviations per √°C (mean −{MAX_SLACK:g} … {MAX_SLACK:g}, "
                      f"sd 0 … {MAX_SLACK:g})")


def steady_wander(given: Any) -> dict[str, float]:
    """``decision.steady_wander``: input → variance fraction of the slow wander."""
    return _per_input(given, "steady_wander", STEADY_WANDER,
                      lambda v: float(v) if is_finite_number(v) and 0.0 <= v < 1.0 else None,
                      "a variance fraction 0 … <1")


def learned_sd_prior(given: Any) -> dict[str, tuple[float, float]]:
    """``decision.learned_sd_prior_friction``: input → [k pseudo-values, their sd] (``[]``: none)."""
    def parse(pair: Any) -> tuple[float, float] | None:
        if isinstance(pair, (list, tuple)) and len(pair) == 0:
            return (0.0, 1.0)
        ok = isinstance(pair, (list, tuple)) and len(pair) == 2 and all(is_finite_number(v) for v in pair)
        return (float(pair[0]), float(pair[1])) if ok and 0 <= pair[0] <= 10_000 and 0 < pair[1] <= 1e6 else None
    parsed = _per_input(given, "learned_sd_prior_friction", {**dict.fromkeys(HEALTHY_DRIFT, (0.0, 1.0)),
                                                             **LEARNED_SD_PRIOR_FRICTION}, parse,
                        "[k pseudo-values 0 … 10000, their sd > 0] in the input's units, or [] for none")
    return {name: prior for name, prior in parsed.items() if prior[0] > 0}
