"""Figures of docs/ALGORITHMS.md: the friction model of §1 and the wear/temperature sensitivities
behind §3 and §4, drawn from ``joint_model.friction`` and the default weight function.

Usage: ``python tools/studies/plot_algorithms.py [--out docs/img/algorithms]``. Deterministic (no random
numbers). Needs matplotlib (a docs-only peer, like ``tools/studies/eval_kl_weights.py``:
``pip install matplotlib``).

Units: speed rad/s (motor side), torque as a fraction of the joint's maximum torque, temperature
°C, wear 0 … 100.
"""

from __future__ import annotations

import argparse
import logging
from pathlib import Path
from typing import Callable

import numpy as np
from numpy.typing import NDArray

from edge_monitor.features.disturbance_weights import WeightFunction
from joint_model.friction import (
    CRITICAL_WEAR,
    DEFAULT_SPEED_LEVELS,
    friction_magnitude,
    jacobian_temperature_wear,
)

log = logging.getLogger("plot_algorithms")

SPEEDS = np.linspace(0.5, 300.0, 600)


def plot_friction(out: Path) -> Path:
    """Three panels: friction vs speed for several temperatures, loads and wear levels."""
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 3, figsize=(12, 3.6), sharey=True)
    cases: tuple[tuple[str, list[float], Callable[[float], NDArray[np.float64]]], ...] = (
        ("temperature ξ [°C] (|τl| = 0.5, ϖ = 0)", [30.0, 40.0, 50.0, 60.0, 70.0],
         lambda x: friction_magnitude(SPEEDS, 0.5, x, 0.0)),
        ("load |τl| (ξ = 40 °C, ϖ = 0)", [0.0, 0.25, 0.5, 0.75],
         lambda x: friction_magnitude(SPEEDS, x, 40.0, 0.0)),
        ("wear ϖ (ξ = 40 °C, |τl| = 0.5)", [0.0, 10.0, 20.0, CRITICAL_WEAR, 50.0],
         lambda x: friction_magnitude(SPEEDS, 0.5, 40.0, x)),
    )
    for ax, (title, values, curve) in zip(axes, cases):
        cmap = plt.get_cmap("viridis")
        for i, value in enumerate(values):
            ax.plot(SPEEDS, curve(value), color=cmap(i / max(len(values) - 1, 1)), label=f"{value:g}")
        for level in DEFAULT_SPEED_LEVELS:
            ax.axvline(level, color="0.85", lw=0.6, zorder=0)
        ax.set_title(title, fontsize=9)
        ax.set_xlabel("motor speed v [rad/s]")
        ax.legend(fontsize=7, loc="upper right")
        ax.grid(alpha=0.3)
    axes[0].set_ylabel("friction τf [fraction of max. torque]")
    fig.suptitle("Steady-state friction model of the default joint (grey: the 12 default speed levels)",
                 fontsize=10)
    fig.tight_layout()
    path = out / "friction_model.png"
    fig.savefig(path, dpi=90)
    plt.close(fig)
    return path


def plot_sensitivities(out: Path) -> Path:
    """∂τf/∂ϖ and ∂τf/∂ξ at ϖ = 35 for several temperatures, and the weight function w(v)."""
    import matplotlib.pyplot as plt

    fig, (ax_s, ax_w) = plt.subplots(1, 2, figsize=(10, 3.6))
    for xi, style in ((30, ":"), (40, "-"), (50, "--")):
        jac = jacobian_temperature_wear(SPEEDS, xi, CRITICAL_WEAR)
        ax_s.plot(SPEEDS, jac[:, 0], "C1" + style, label=f"∂τf/∂ξ at {xi} °C [1/°C]")
    jac = jacobian_temperature_wear(SPEEDS, 40.0, CRITICAL_WEAR)
    ax_s.plot(SPEEDS, jac[:, 1], "C0-", lw=2, label="∂τf/∂ϖ at ϖ = 35 [1/wear unit]")
    ax_s.axhline(0.0, color="0.5", lw=0.6)
    ax_s.set_xlim(0, 160)
    ax_s.set_xlabel("motor speed v [rad/s]")
    ax_s.set_title("Sensitivity of friction to wear and to temperature", fontsize=9)
    ax_s.legend(fontsize=7)
    ax_s.grid(alpha=0.3)
    weights = WeightFunction()
    ax_w.plot(SPEEDS, weights(SPEEDS), "C2")
    ax_w.set_xlabel("motor speed v [rad/s]")
    ax_w.set_ylabel("w(v)")
    ax_w.set_title(f"w(v) = sech(βv)·tanh(αv), α = {weights.alpha:g}, β = {weights.beta:g} s/rad", fontsize=9)
    ax_w.grid(alpha=0.3)
    fig.tight_layout()
    path = out / "sensitivities_and_weights.png"
    fig.savefig(path, dpi=90)
    plt.close(fig)
    return path


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=Path, default=Path("docs/img/algorithms"), help="output directory")
    args = parser.parse_args(argv)
    logging.basicConfig(level=logging.INFO, format="%(message)s")
    try:
        import matplotlib
    except ImportError:
        print("plot_algorithms: needs matplotlib (pip install matplotlib)")
        return 2
    matplotlib.use("Agg")
    args.out.mkdir(parents=True, exist_ok=True)
    for path in (plot_friction(args.out), plot_sensitivities(args.out)):
        print(f"wrote {path}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
