#!/usr/bin/env python3
"""How far a joint's learned wear-score spread is from the spread its warm-up then shows, and what a floor or a
prior on the learned standard deviation would change (docs/WITHOUT_MOTOR_TEMPERATURE.md, "Not met").

The wear score is the signed root of a likelihood ratio against no wear: ≈ N(0, 1) on a healthy joint by
construction. The warm-up nominal learns its mean and standard deviation s₀ from the joint's first
``decision.n_nominal`` values (cold cycles); the detector then tests values in units of s₀. Per joint this study
takes those first values as the learning window and the rest of its rows up to ``--until`` as the warm-up, and
reports s₀, the warm-up's own standard deviation, their ratio r (the spread the calibration's law describes over
joints) and the warm-up's mean shift in units of s₀; then the same with s₀ replaced by

* a floor, max(s₀, f), and
* a prior of k pseudo-values at 1 (the score's own variance), √((n − 1)·s₀² + k) / (n − 1 + k)),

with the spread of log r over joints and the largest r and shifts, the joints that decide the tail.

``--refit M[,M…]``: the law a warm-up calibration would draw its joints from (each joint's mean and spread over its
warm-up, in the units of its nominal; mean ± sd and spread ± sd over joints) as shipped (the learned sd, with the
prior where the robot has no motor temperature) and with the sd fitted again to the joint's next M values, the law
then over the values after those. ``--thresholds``: the Gaussian thresholds [nats] of each such law, and of the
shipped one with the spread known exactly (sd 0) and with the mean's spread cut to the learning error
(``--nominals`` × 4 detectors, 4 000 cycles; ≈ 4 min a law); ``--shipped-law``: those of the shipped law alone,
without series (``--seeds`` is then ignored).

Usage: ``python tools/studies/learned_spread_study.py --seeds 7341-7380 --no-motor-temperature``
(``--seeds 8201-8213,8401-8413`` with one); reads the per-cycle series studies.series keeps (computed if missing,
≈ 4 min a robot).
"""

from __future__ import annotations

import argparse
import sys
from dataclasses import dataclass
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))

from edge_monitor.pipeline.decision_config import DecisionConfig  # noqa: E402
from studies.series import robot_series  # noqa: E402
from studies.settings import parse_seeds  # noqa: E402

FLOORS = (0.5, 0.6, 0.7, 0.8, 0.9)
PRIOR_COUNTS = (20, 60, 120)


@dataclass(frozen=True)
class JointSpread:
    """One joint: learned sd s₀, the warm-up's sd and mean (wear-score units)."""

    seed: int
    joint: int
    learned_mean: float
    learned_sd: float
    warm_mean: float
    warm_sd: float


def joint_spreads(seed: int, cycles: int, motor_temperature: bool, n_nominal: int, until: int) -> list[JointSpread]:
    """Per joint of one robot, its learning window against the rest of its warm-up."""
    out = []
    for joint, rows in robot_series(seed, cycles, motor_temperature=motor_temperature).items():
        values = np.array([r["wear_score"] for r in rows if r["cycle"] <= until], dtype=float)
        values = values[np.isfinite(values)]
        if values.size < 2 * n_nominal:
            continue
        learn, warm = values[:n_nominal], values[n_nominal:]
        out.append(JointSpread(seed, joint, float(learn.mean()), float(learn.std(ddof=1)),
                               float(warm.mean()), float(warm.std(ddof=1))))
    return out


def summarise(joints: list[JointSpread], scale: np.ndarray, label: str) -> str:
    """One line: spread of log r over joints, the three largest r and |shift|, share of joints whose sd moved."""
    s0 = np.array([j.learned_sd for j in joints])
    r = np.array([j.warm_sd for j in joints]) / scale
    shift = np.abs(np.array([j.warm_mean - j.learned_mean for j in joints])) / scale
    return (f"{label:<14} r {r.mean():.3f} ± {r.std():.3f}, sd(log r) {np.log(r).std():.3f}, largest r "
            f"{np.round(np.sort(r)[-3:], 2).tolist()}, largest |shift| {np.round(np.sort(shift)[-3:], 2).tolist()}, "
            f"joints whose sd is raised {np.mean(scale > s0 + 1e-12):.2f}")


def report(joints: list[JointSpread], n_nominal: int, worst: int) -> None:
    s0 = np.array([j.learned_sd for j in joints])
    print(f"{len(joints)} joints; learned sd s0 quantiles 5/25/50/75/95 %: "
          f"{np.round(np.percentile(s0, [5, 25, 50, 75, 95]), 3).tolist()}; warm-up sd: "
          f"{np.round(np.percentile([j.warm_sd for j in joints], [5, 25, 50, 75, 95]), 3).tolist()}")
    r = np.array([j.warm_sd for j in joints]) / s0
    print(f"corr(r, s0) {np.corrcoef(r, s0)[0, 1]:.2f}")
    print(summarise(joints, s0, "as learned"))
    for f in FLOORS:
        print(summarise(joints, np.maximum(s0, f), f"floor {f:.1f}"))
    for k in PRIOR_COUNTS:
        print(summarise(joints, np.sqrt(((n_nominal - 1) * s0 ** 2 + k) / (n_nominal - 1 + k)), f"prior k={k}"))
    print(f"the {worst} joints of largest r (as learned):")
    for j in sorted(joints, key=lambda j: j.warm_sd / j.learned_sd)[-worst:]:
        print(f"  seed {j.seed} joint {j.joint}: s0 {j.learned_sd:.3f}, warm-up sd {j.warm_sd:.3f}, "
              f"r {j.warm_sd / j.learned_sd:.2f}, shift {(j.warm_mean - j.learned_mean) / j.learned_sd:+.2f}")


@dataclass(frozen=True)
class Law:
    """Over joints: the warm-up's mean and spread in the units a nominal scales by, each as mean ± sd."""

    label: str
    mean: float
    mean_sd: float
    spread: float
    spread_sd: float

    def text(self) -> str:
        return (f"{self.label:<28} mean {self.mean:+.3f} ± {self.mean_sd:.3f}, spread {self.spread:.3f} ± "
                f"{self.spread_sd:.3f}")


def warm_up_laws(series: list[np.ndarray], n_nominal: int, prior: tuple[float, float],
                 refits: tuple[int, ...]) -> list[Law]:
    """The shipped law (each joint's values over its warm-up in units of its learned sd, widened by ``prior`` =
    (k, sd): k pseudo-values of that sd) and, per M in ``refits``, the law with the sd fitted again to the next M
    values."""
    def law(label: str, scaled: list[np.ndarray]) -> Law:
        m = np.array([z.mean() for z in scaled])
        sd = np.array([z.std() for z in scaled])
        return Law(label, float(m.mean()), float(m.std()), float(sd.mean()), float(sd.std()))

    usable = [x for x in series if x.size > n_nominal + max(refits, default=0) + 30]
    shipped = []
    for x in usable:
        s0 = x[:n_nominal].std(ddof=1)
        k, sd = prior
        s = np.sqrt(((n_nominal - 1) * s0 ** 2 + k * sd ** 2) / (n_nominal - 1 + k))
        shipped.append((x[n_nominal:len(x)] - x[:n_nominal].mean()) / s)
    out = [law(f"as shipped (prior k={prior[0]:g})", shipped)]
    for m in refits:
        out.append(law(f"sd refitted to next {m}", [(x[n_nominal + m:] - x[:n_nominal].mean())
                                                     / x[n_nominal:n_nominal + m].std(ddof=1) for x in usable]))
    return out


def law_thresholds(laws: list[Law], motor_temperature: bool, nominals: int) -> None:
    """The warm-up wear-score thresholds of each law (the shipped detector settings otherwise), and of the shipped
    law with its spread known (sd 0) and with the mean's spread cut to the learning error, 1/√n."""
    from dataclasses import replace

    from edge_monitor.stats.gaussian_calibration import GaussianBudget, thresholds

    base = DecisionConfig().detector_config("wear", friction_temperature=not motor_temperature).gaussian_settings(
        "warm-up")
    n = DecisionConfig().n_nominal
    variants = [(law.label, replace(base, drift_mean=(law.mean,), drift_sd=(law.mean_sd,), spread_mean=(law.spread,),
                                    spread_sd=(law.spread_sd,))) for law in laws]
    first = variants[0][1]
    variants += [("as shipped, spread known", replace(first, spread_sd=(0.0,))),
                 ("as shipped, mean's sd 1/√n", replace(first, drift_sd=(1 / np.sqrt(n),)))]
    targets = (50.0, 200.0, 1e3, 1e4, DecisionConfig(budget_period="week").arl0, DecisionConfig().arl0)
    budget = GaussianBudget(nominals=nominals, streams=4, steps=4000)
    print(f"thresholds [nats] at ARL0 {', '.join(f'{t:.3g}' for t in targets)} (± bootstrap se; "
          f"{nominals} × 4 detectors × 4000 cycles; e: extrapolated):")
    for label, settings in variants:
        found = thresholds(settings, ((1.0,),), targets, budget)
        print(f"  {label:<28} " + "  ".join(f"{t.threshold:.2f}±{t.h_se:.2f}{'e' if t.method != 'simulated' else ''}"
                                            for t in found), flush=True)


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--seeds", default="", help="e.g. 7341-7380 or 8201-8213,8401-8413")
    ap.add_argument("--cycles", type=int, default=1000)
    ap.add_argument("--until", type=int, default=800, help="last cycle counted as the warm-up (default 800)")
    ap.add_argument("--no-motor-temperature", action="store_true", help="robots whose controller sends none")
    ap.add_argument("--worst", type=int, default=5, help="joints of largest r listed (default 5)")
    ap.add_argument("--refit", default="", help="M[,M…]: the warm-up law with the sd fitted again to the next M values")
    ap.add_argument("--thresholds", action="store_true", help="the Gaussian thresholds of those laws (≈ 4 min each)")
    ap.add_argument("--nominals", type=int, default=1024, help="simulated nominals per law (default 1024)")
    ap.add_argument("--shipped-law", action="store_true",
                    help="no series: the thresholds of the shipped warm-up law of the wear score and its two variants")
    args = ap.parse_args(argv)
    if args.shipped_law:
        c = DecisionConfig().detector_config("wear", friction_temperature=args.no_motor_temperature).gaussian_settings(
            "warm-up")
        shipped = Law("shipped law", c.drift_mean[0], c.drift_sd[0], c.spread_mean[0], c.spread_sd[0])
        print(shipped.text())
        law_thresholds([shipped], not args.no_motor_temperature, args.nominals)
        return
    if not args.seeds:
        ap.error("--seeds: the robots whose series to read (or --shipped-law without series)")
    n_nominal = DecisionConfig().n_nominal
    joints = [j for seed in parse_seeds(args.seeds)
              for j in joint_spreads(seed, args.cycles, not args.no_motor_temperature, n_nominal, args.until)]
    if not joints:
        sys.exit("learned_spread_study: no joint has enough rows; more --cycles or a later --until")
    report(joints, n_nominal, args.worst)
    if args.refit or args.thresholds:
        series = [np.array([r["wear_score"] for r in rows if r["cycle"] <= args.until], dtype=float)
                  for seed in parse_seeds(args.seeds)
                  for rows in robot_series(seed, args.cycles, motor_temperature=not args.no_motor_temperature).values()]
        series = [x[np.isfinite(x)] for x in series]
        prior = DecisionConfig().learned_sd_prior_friction.get("wear_score", (0.0, 1.0)) \
            if args.no_motor_temperature else (0.0, 1.0)
        laws = warm_up_laws(series, n_nominal, prior,
                            tuple(int(m) for m in args.refit.split(",") if m.strip()))
        for law in laws:
            print(law.text())
        if args.thresholds:
            law_thresholds(laws, not args.no_motor_temperature, args.nominals)


if __name__ == "__main__":
    main()
