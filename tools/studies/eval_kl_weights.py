"""Pd of kl.raw vs kl.weighted under temperature spread (issue 5 quality target, docs/ALGORITHMS.md §4/§8).

For each temperature spread s, the lubricant temperature of every cycle is drawn from U(30, 30 + s) °C
(s = 25 is the issue's U(30, 55)). Per replicate, a fresh KLMonitor learns its nominal model from K
wear-0 cycles under that spread, then sees N wear-0 cycles (H0) and N wear-35 cycles (H1). The
threshold is the empirical 99 % quantile of the H0 values (1 % false alarms); Pd is the fraction of
H1 values above it. Replicates repeat the nominal learning with new data (Pd depends on which K
cycles were learned); the table gives their mean and range.

Weighted variants: the published weights (α = 1.45e-2, β = 4.55e-2, fitted to the real joint in the
thesis) and weights fitted by ``edge-monitor fit-weights``' procedure to labelled runs of the same
generator (healthy vs wear 35, both with ξ ~ U(30, 70)).

Data: ``edge_monitor.commands.fit_weights.simulate_cycles`` (test cycle straight from the §1 model)
or, with ``--source sim``, the project simulator (``sim_controller``), one joint, samples taken
before the wire (see ``sim_cycles``). Both draw the load (gravity torque at the test angle) per cycle
from U(0.3, 0.7) by default (``--load``, ``--sim-load``); ``--no-center`` evaluates the uncentred
detector.

Needs matplotlib for ``--png`` (a benchmark/eval-only peer: ``pip install matplotlib``).

    python tools/studies/eval_kl_weights.py --cycles 500 --replicates 3 --png docs/img/kl_pd_vs_spread.png
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from typing import Callable

import numpy as np

from edge_monitor.commands.fit_weights import causally_centred, simulate_cycles
from edge_monitor.features.disturbance_weights import WeightFunction, fit_index_weights, fit_weight_function
from edge_monitor.features.kl_monitor import KLConfig, KLMonitor

Source = Callable[[int, float, tuple[float, float], np.random.Generator], tuple[np.ndarray, np.ndarray]]


#: Per-cycle gravity (load) torque of the model generator (``--load``): the simulator's U(0.3, 0.7).
MODEL_LOAD: tuple[float, float] = (0.3, 0.7)
#: Load range |τl| of the simulator runs (``--sim-load``); None: the simulator's default U(0.3, 0.7).
SIM_LOAD: tuple[float, float] | None = None
#: KLMonitor(center=...) (``--no-center`` turns it off).
CENTER = True


def model_cycles(n: int, wear: float, temperature: tuple[float, float], rng: np.random.Generator
                 ) -> tuple[np.ndarray, np.ndarray]:
    torque, speed, _ = simulate_cycles(n, wear, temperature, rng, gravity=MODEL_LOAD)
    return torque, np.broadcast_to(speed, torque.shape)


def sim_cycles(n: int, wear: float, temperature: tuple[float, float], rng: np.random.Generator
               ) -> tuple[np.ndarray, np.ndarray]:
    """Cycles of the project simulator (one joint, default test cycle incl. production motion,
    load |τl| ~ U(0.3, 0.7), PI speed loop, measurement noise). Uses the controller's per-cycle
    simulation step directly (before frame encoding): the KL detector's input is the same sample
    stream the agent decodes, without the 5e-5 torque quantisation."""
    from sim_controller.config import SimConfig
    from sim_controller.controller import Controller
    from sim_controller.wear_scenarios import WearProfile

    config = SimConfig(joints=1, cycles=n, seed=int(rng.integers(2**31)), temperature_range=temperature,
                       wear=(WearProfile(initial=wear),))
    if SIM_LOAD is not None:
        config = config.with_(load_range=SIM_LOAD)
    torques, speeds = [], []
    for cycle in Controller(config).simulated_cycles():
        torques.append(cycle.sim["torque"][0])
        speeds.append(cycle.sim["speed"][0])
    size = min(t.size for t in torques)               # production delay varies the cycle length
    return np.array([t[:size] for t in torques]), np.array([s[:size] for s in speeds])


#: The published weights (the agent's defaults).
PUBLISHED = WeightFunction()


def new_monitor(k: int, weights: WeightFunction = PUBLISHED) -> KLMonitor:
    """The agent's KL monitor (its defaults, sample selection included) learning from ``k`` cycles, with
    ``weights`` for the weighted channel and the centring of :data:`CENTER`. Without a friction model
    it has no temperature compensation (these runs draw a new temperature per cycle anyway)."""
    return KLMonitor(KLConfig(n_nominal_cycles=k, alpha=weights.alpha, beta=weights.beta, center=CENTER))


def kl_values(monitor: KLMonitor, torque: np.ndarray, speed: np.ndarray) -> np.ndarray:
    out = []
    for c in range(torque.shape[0]):
        monitor.update_samples(torque[c], speed[c])
        r = monitor.end_cycle(c)
        out.append((np.nan, np.nan) if r.raw is None else (r.raw, r.weighted))
    return np.array(out)


def fitted_weights(source: Source, rng: np.random.Generator, n: int = 200) -> WeightFunction:
    """Weights fitted to labelled runs (ξ ~ U(30, 70), load as the source draws it); with centring
    on, fitted to the causally centred torque the weighted channel sees."""
    healthy, speed = source(n, 0.0, (30.0, 70.0), rng)
    faulty, _ = source(n, 35.0, (30.0, 70.0), rng)
    size = min(healthy.shape[1], faulty.shape[1])     # simulator cycles differ by a few ticks
    healthy, faulty, speed = healthy[:, :size], faulty[:, :size], speed[:, :size].mean(axis=0)
    if CENTER:
        healthy, faulty = causally_centred(healthy), causally_centred(faulty)
    alpha, beta = fit_weight_function(speed, fit_index_weights(healthy, faulty))
    return WeightFunction(alpha, beta)


def pd_at_1pct(h0: np.ndarray, h1: np.ndarray) -> float:
    threshold = np.quantile(h0[np.isfinite(h0)], 0.99)
    return float(np.mean(h1 > threshold))


def study(source: Source, spreads: list[float], n_cycles: int, replicates: int, k: int, wear: float,
          weights: dict[str, WeightFunction], rng: np.random.Generator) -> dict[str, dict[float, list[float]]]:
    pd: dict[str, dict[float, list[float]]] = {"raw": {}, **{name: {} for name in weights}}
    for s in spreads:
        temperature = (30.0, 30.0 + s)
        for _ in range(replicates):
            monitors = {name: new_monitor(k, w) for name, w in weights.items()}
            data = {label: source(n, wr, temperature, rng)
                    for label, n, wr in (("nominal", k, 0.0), ("h0", n_cycles, 0.0), ("h1", n_cycles, wear))}
            values = {}
            for name, mon in monitors.items():
                kl_values(mon, *data["nominal"])
                values[name] = (kl_values(mon, *data["h0"]), kl_values(mon, *data["h1"]))
            first = next(iter(values.values()))
            pd["raw"].setdefault(s, []).append(pd_at_1pct(first[0][:, 0], first[1][:, 0]))
            for name, (h0, h1) in values.items():
                pd[name].setdefault(s, []).append(pd_at_1pct(h0[:, 1], h1[:, 1]))
        print(f"spread {s:4.0f} °C: " + ", ".join(f"{name} {np.mean(v[s]):.3f}" for name, v in pd.items()),
              file=sys.stderr, flush=True)
    return pd


def example_densities(source: Source, rng: np.random.Generator, k: int) -> dict[str, np.ndarray]:
    mon = new_monitor(k)
    kl_values(mon, *source(k, 0.0, (40.0, 40.0), rng))
    out: dict[str, np.ndarray] = {}
    for label, wear in (("wear 0", 0.0), ("wear 35", 35.0)):
        torque, speed = source(1, wear, (40.0, 40.0), rng)
        mon.update_samples(torque[0], speed[0])
        density = mon.end_cycle(99).density
        assert density is not None
        for key, name in (("grid", "grid"), ("nominal", "nominal"), (label, "cycle")):
            values = density[name]
            assert values is not None
            out[key] = values
    return out


def plot(pd: dict[str, dict[float, list[float]]], densities: dict[str, np.ndarray], path: str, title: str) -> None:
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, (ax, ax2) = plt.subplots(1, 2, figsize=(11, 4.2))
    for name, curve in pd.items():
        s = sorted(curve)
        mean = [np.mean(curve[x]) for x in s]
        ax.plot(s, mean, marker="o", label=f"kl.{name}" if name == "raw" else f"kl.weighted ({name})")
        ax.fill_between(s, [min(curve[x]) for x in s], [max(curve[x]) for x in s], alpha=0.2)
    ax.set_xlabel("temperature spread s [°C]  (ξ ~ U(30, 30 + s) per cycle)")
    ax.set_ylabel("Pd at 1 % false alarms")
    ax.set_ylim(-0.02, 1.02)
    ax.grid(alpha=0.3)
    ax.legend(loc="lower left")
    ax.set_title(title)
    ax2.plot(densities["grid"], densities["nominal"], "k-", label="nominal (K cycles)")
    ax2.plot(densities["grid"], densities["wear 0"], label="one cycle, wear 0")
    ax2.plot(densities["grid"], densities["wear 35"], label="one cycle, wear 35")
    ax2.set_xlabel("joint torque − cycle mean [fraction of max]" if CENTER else "joint torque [fraction of max]")
    ax2.set_ylabel("density (raw channel)")
    ax2.set_title("torque densities at 40 °C")
    ax2.grid(alpha=0.3)
    ax2.legend()
    fig.tight_layout()
    fig.savefig(path, dpi=110)


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--source", choices=("model", "sim"), default="model")
    p.add_argument("--cycles", type=int, default=500, help="Monte Carlo cycles per hypothesis and replicate")
    p.add_argument("--replicates", type=int, default=3)
    p.add_argument("--nominal", type=int, default=10, help="K nominal cycles")
    p.add_argument("--wear", type=float, default=35.0)
    p.add_argument("--spreads", default="0,5,10,15,20,25,30,35,40")
    p.add_argument("--seed", type=int, default=5)
    p.add_argument("--sim-load", type=float, nargs=2, metavar=("LO", "HI"),
                   help="with --source sim: per-cycle load range |τl| (default: the simulator's 0.3 0.7)")
    p.add_argument("--load", type=float, nargs=2, metavar=("LO", "HI"), default=(0.3, 0.7),
                   help="with --source model: per-cycle gravity torque range (default 0.3 0.7; '0.3 0.3' fixed)")
    p.add_argument("--no-center", action="store_true", help="KLMonitor(center=False): the uncentred detector")
    p.add_argument("--png", help="write the Pd-vs-spread figure here")
    p.add_argument("--json", help="write the numbers here")
    args = p.parse_args(argv)
    rng = np.random.default_rng(args.seed)
    global SIM_LOAD, MODEL_LOAD, CENTER
    SIM_LOAD = None if args.sim_load is None else (args.sim_load[0], args.sim_load[1])
    MODEL_LOAD = (args.load[0], args.load[1])
    CENTER = not args.no_center
    source: Source = model_cycles if args.source == "model" else sim_cycles
    t0 = time.perf_counter()
    fitted = fitted_weights(source, rng)
    print(f"fitted weights: alpha={fitted.alpha:.4g} beta={fitted.beta:.4g}", file=sys.stderr)
    weights = {"published": WeightFunction(), "fitted": fitted}
    spreads = [float(x) for x in args.spreads.split(",")]
    pd = study(source, spreads, args.cycles, args.replicates, args.nominal, args.wear, weights, rng)
    print("| spread [°C] | " + " | ".join(f"Pd {n}" for n in pd) + " |")
    print("|---|" + "---|" * len(pd))
    for s in spreads:
        cells = [f"{np.mean(pd[n][s]):.3f} ({min(pd[n][s]):.2f}–{max(pd[n][s]):.2f})" for n in pd]
        print(f"| {s:.0f} | " + " | ".join(cells) + " |")
    print(f"\nsource={args.source} cycles/hypothesis={args.cycles} replicates={args.replicates} K={args.nominal} "
          f"wear={args.wear} center={CENTER} "
          f"load={MODEL_LOAD if args.source == 'model' else (SIM_LOAD or 'sim default')} fitted alpha={fitted.alpha:.4g} beta={fitted.beta:.4g} "
          f"({time.perf_counter() - t0:.0f} s)")
    if args.json:
        with open(args.json, "w") as fh:
            json.dump({"pd": {n: {str(s): v for s, v in c.items()} for n, c in pd.items()},
                       "fitted": fitted.to_dict(), "args": vars(args)}, fh, indent=1)
    if args.png:
        plot(pd, example_densities(source, rng, args.nominal), args.png,
             f"wear {args.wear:.0f} vs 0, {args.cycles} cycles/hyp., {args.replicates} nominal learnings")
    return 0


if __name__ == "__main__":
    sys.exit(main())
