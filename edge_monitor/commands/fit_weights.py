"""``edge-monitor fit-weights``: fit disturbance-rejecting weights from labelled runs (docs/ALGORITHMS.md §4).

Input: two CSV files of aligned cycles, healthy and faulty (critical wear), both recorded under the
disturbance spread (e.g. temperature). Each file has a header ``cycle,sample,speed,torque``
(speed in rad/s, torque dimensionless); ``sample`` is the index within the cycle, so the same
sample of the repeated trajectory is one element of the batch vectors. With ``--simulate`` the runs
are drawn straight from the friction model of docs/ALGORITHMS.md §1 instead (a small stand-in for
the simulator; ``--write-csv`` writes them out).

Output (stdout or ``-o/--out``): JSON ``{"alpha", "beta", "index_weights", "speeds", ...}``; alpha
and beta go into the agent configuration of the weighted KL channel.

Memory stays bounded whatever the options or files say: a CSV must be a regular file of at most
:data:`MAX_CSV_BYTES`, and cycles × samples per cycle at most :data:`MAX_CELLS` (--cycles, a sample
index); options outside their physical range are usage errors (exit code 2).
"""

from __future__ import annotations

import argparse
import json
import math
import sys
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from edge_monitor.features.disturbance_weights import WeightFitError, fit_index_weights, fit_weight_function
from joint_model import CRITICAL_WEAR, DEFAULT_SPEED_LEVELS, FRICTION_NOISE_STD, WEAR_MAX, friction
from protocol.console import EXIT_FAILURE, EXIT_USAGE, UsageError
from protocol.files import NotARegularFile, require_regular

#: Largest CSV read [bytes].
MAX_CSV_BYTES = 512 << 20
#: Largest cycles × samples-per-cycle matrix [numbers] (128 MiB; the fit holds a few such).
MAX_CELLS = 1 << 24


class CycleDataError(ValueError):
    """A labelled-run file that cannot be used (missing columns, ragged cycles)."""


@dataclass(frozen=True)
class CycleModel:
    """Test cycle of the stand-in generator. For each speed level: ramp 0 → +v, plateau +v, ramp
    +v → −v, plateau −v, ramp −v → 0 (linear ramps of ``ramp_s`` per |v| step, plateaus of
    ``plateau_s``), sampled at ``rate_hz``. Torque per sample:

    ``τ = gravity + sign(v)·[τf(|v|, load, ξ, ϖ) + e_level] + n``, with the gravity torque the same in
    both directions and every cycle, ``e_level ~ N(0, model_error_std²)`` drawn per cycle and speed
    level (model error of a friction datum, docs/ALGORITHMS.md §1) and sample noise ``n ~ N(0,
    noise_std²)``. Inertial torque in the ramps is ignored (quasi-static).
    """

    levels: tuple[float, ...] = DEFAULT_SPEED_LEVELS
    plateau_s: float = 1.1
    ramp_s: float = 0.1
    rate_hz: float = 500.0
    gravity: float = 0.3
    load: float = 0.3
    model_error_std: float = FRICTION_NOISE_STD
    noise_std: float = 2e-3

    def speed_profile(self) -> tuple[NDArray[np.float64], NDArray[np.int64]]:
        """(speed [rad/s], level index per sample) of one cycle."""
        n_plateau = int(round(self.plateau_s * self.rate_hz))
        n_ramp = int(round(self.ramp_s * self.rate_hz))
        ramp = np.arange(1, n_ramp + 1) / n_ramp
        reverse = 1.0 - 2.0 * np.arange(1, 2 * n_ramp + 1) / (2 * n_ramp)   # +1 → −1 in 2·ramp_s
        speeds, levels = [], []
        for k, v in enumerate(self.levels):
            parts = [v * ramp, np.full(n_plateau, v), v * reverse,
                     np.full(n_plateau, -v), -v * (1 - ramp)]
            block = np.concatenate(parts)
            speeds.append(block)
            levels.append(np.full(block.size, k))
        return np.concatenate(speeds), np.concatenate(levels)


def simulate_cycles(n_cycles: int, wear: float, temperature: tuple[float, float],
                    rng: np.random.Generator, model: CycleModel = CycleModel(),
                    gravity: tuple[float, float] | None = None
                    ) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]:
    """Draw ``n_cycles`` test cycles at wear ``wear`` with the lubricant temperature of each cycle
    uniform on ``temperature = (lo, hi)`` [°C]. Returns (torque [n_cycles, n_samples], speed
    [n_samples] rad/s, temperature per cycle [°C]). With ``gravity = (lo, hi)`` the gravity (load)
    torque at the test angle is drawn per cycle from U(lo, hi) (dimensionless; a pure location shift
    of the cycle, the friction load stays ``model.load``), else it is ``model.gravity``. The extra
    draws come after the others, so without ``gravity`` the stream is unchanged."""
    speed, level = model.speed_profile()
    xi = rng.uniform(temperature[0], temperature[1], size=n_cycles)
    sign = np.sign(speed)
    tau_f = friction(speed[None, :], model.load, xi[:, None], wear)
    errors = rng.normal(0.0, model.model_error_std, size=(n_cycles, len(model.levels)))
    noise = rng.normal(0.0, model.noise_std, size=(n_cycles, speed.size))
    g = np.full(n_cycles, model.gravity) if gravity is None else rng.uniform(gravity[0], gravity[1], n_cycles)
    torque = g[:, None] + tau_f + sign[None, :] * errors[:, level] + noise
    return torque, speed, xi


# -- CSV input/output ---------------------------------------------------------------------------
def write_cycles_csv(path: Path, torque: NDArray[np.float64], speed: NDArray[np.float64]) -> None:
    """Write cycles as ``cycle,sample,speed,torque`` rows."""
    n_cycles, n_samples = torque.shape
    rows = np.column_stack([np.repeat(np.arange(n_cycles), n_samples), np.tile(np.arange(n_samples), n_cycles),
                            np.tile(speed, n_cycles), torque.reshape(-1)])
    np.savetxt(path, rows, fmt=["%d", "%d", "%.4f", "%.6f"], delimiter=",", header="cycle,sample,speed,torque",
               comments="")


def read_cycles_csv(path: Path) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Read ``cycle,sample,speed,torque`` rows (any column order, header required) into
    (torque [n_cycles, n_samples], speed [n_samples]). Incomplete cycles are skipped with a note."""
    try:
        require_regular(path)
        if path.stat().st_size > MAX_CSV_BYTES:
            raise CycleDataError(f"{path}: larger than {MAX_CSV_BYTES} bytes")
        with open(path) as fh:
            header = [name.strip() for name in fh.readline(4096).split(",")]
            missing = {"cycle", "sample", "speed", "torque"} - set(header)
            if missing:
                raise CycleDataError(f"{path}: missing column(s) {sorted(missing)}; "
                                     "header must name cycle,sample,speed,torque")
            data = np.loadtxt(fh, delimiter=",", ndmin=2)
    except NotARegularFile as exc:
        raise CycleDataError(f"{path}: {exc.reason}; give a CSV file") from None
    except OSError as exc:
        raise CycleDataError(f"{path}: cannot read ({exc})") from None
    except ValueError as exc:
        raise CycleDataError(f"{path}: not numeric CSV ({exc})") from None
    if data.shape[0] == 0:
        raise CycleDataError(f"{path}: no rows")
    if data.shape[1] != len(header):
        raise CycleDataError(f"{path}: rows have {data.shape[1]} cells, the header {len(header)}")
    col = {name: data[:, header.index(name)] for name in ("cycle", "sample", "speed", "torque")}
    cycles = np.unique(col["cycle"])
    sample = col["sample"]
    if not (np.all(np.isfinite(sample)) and np.all(sample == np.round(sample)) and sample.min() >= 0):
        raise CycleDataError(f"{path}: column sample must hold integers ≥ 0 (the index within the cycle)")
    n_samples = int(sample.max()) + 1
    if cycles.size * n_samples > MAX_CELLS or not np.all(np.isfinite(cycles)):
        raise CycleDataError(f"{path}: {cycles.size} cycles × {n_samples} samples (sample index up to "
                             f"{n_samples - 1}) is more than {MAX_CELLS} values; check the sample column")
    index = sample.astype(np.int64)
    torque = np.full((cycles.size, n_samples), np.nan)
    torque[np.searchsorted(cycles, col["cycle"]), index] = col["torque"]
    first = col["cycle"] == cycles[0]
    speed = np.full(n_samples, np.nan)
    speed[index[first]] = col["speed"][first]
    complete = np.all(np.isfinite(torque), axis=1)
    if not complete.all():
        print(f"{path}: skipping {int((~complete).sum())} incomplete cycle(s)", file=sys.stderr)
        torque = torque[complete]
    if not np.all(np.isfinite(speed)):
        raise CycleDataError(f"{path}: the first cycle does not cover samples 0 … {n_samples - 1}")
    return torque, speed


# -- command ------------------------------------------------------------------------------------
def causally_centred(torque: NDArray[np.float64]) -> NDArray[np.float64]:
    """``τ_t − m_t`` per cycle (row), ``m_t`` the running mean of the cycle up to sample t: the
    quantity the centred KL detector weights (:class:`edge_monitor.features.kl_monitor.KLMonitor`,
    ``center=True``); invariant to a per-cycle constant load torque."""
    return torque - np.cumsum(torque, axis=1) / np.arange(1, torque.shape[1] + 1)


def fit(healthy: NDArray[np.float64], faulty: NDArray[np.float64], speed: NDArray[np.float64],
        center: bool = True) -> dict[str, Any]:
    """Fit α, β. ``center=True`` fits to causally centred torque (for the default, centred KL
    detector); ``False`` to the torque itself (for ``KLMonitor(center=False)``)."""
    if center:
        healthy, faulty = causally_centred(healthy), causally_centred(faulty)
    w_index = fit_index_weights(healthy, faulty)
    alpha, beta = fit_weight_function(speed, w_index)
    return {"alpha": alpha, "beta": beta, "index_weights": [round(float(x), 6) for x in w_index],
            "speeds": [round(float(x), 4) for x in speed],
            "n_healthy": int(healthy.shape[0]), "n_faulty": int(faulty.shape[0]), "center": bool(center)}


def add_parser(subparsers: argparse._SubParsersAction) -> None:
    p = subparsers.add_parser("fit-weights", help="fit disturbance-rejecting KL weights w(v) from labelled runs",
                              description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--healthy", type=Path, help="CSV of healthy cycles (cycle,sample,speed,torque)")
    p.add_argument("--faulty", type=Path, help="CSV of faulty (critical wear) cycles, same trajectory")
    p.add_argument("--simulate", action="store_true", help="generate both runs from the §1 model instead")
    p.add_argument("--cycles", type=int, default=200, help="cycles per class with --simulate (default 200)")
    p.add_argument("--wear", type=float, default=CRITICAL_WEAR, help="wear of the faulty class (default 35)")
    p.add_argument("--temperature", type=float, nargs=2, default=(30.0, 70.0), metavar=("LO", "HI"),
                   help="temperature spread °C per cycle with --simulate (default 30 70)")
    p.add_argument("--load", type=float, nargs=2, metavar=("LO", "HI"),
                   help="with --simulate: per-cycle gravity (load) torque U(LO, HI) (default: fixed 0.3)")
    p.add_argument("--no-center", action="store_true",
                   help="fit to the torque itself, for an uncentred KL detector (default: causally centred torque)")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--write-csv", type=Path, metavar="DIR", help="with --simulate: also write healthy.csv/faulty.csv")
    p.add_argument("-o", "--out", type=Path, help="write the JSON here instead of stdout")
    p.set_defaults(func=run)


def check_simulation(args: argparse.Namespace) -> None:
    """Usage errors for --simulate options outside their range (before anything is allocated)."""
    samples = CycleModel().speed_profile()[0].size
    if not 2 <= args.cycles <= MAX_CELLS // samples:
        raise UsageError(f"--cycles {args.cycles}: give 2 … {MAX_CELLS // samples} cycles per class "
                         f"({samples} samples each)")
    low, high = args.temperature
    if not (math.isfinite(low) and math.isfinite(high) and -40.0 <= low < high <= 150.0):
        raise UsageError(f"--temperature {low:g} {high:g}: give LO < HI within -40 … 150 °C")
    if args.load is not None and not (all(math.isfinite(x) for x in args.load)
                                      and -10.0 <= args.load[0] <= args.load[1] <= 10.0):
        raise UsageError(f"--load {args.load[0]:g} {args.load[1]:g}: give LO ≤ HI within -10 … 10")
    if not (math.isfinite(args.wear) and 0.0 <= args.wear <= WEAR_MAX):
        raise UsageError(f"--wear {args.wear:g}: give 0 … {WEAR_MAX:g}")
    if args.seed < 0:
        raise UsageError(f"--seed {args.seed}: give an integer ≥ 0")


def _write_csvs(folder: Path, healthy: NDArray[np.float64], faulty: NDArray[np.float64],
                speed: NDArray[np.float64]) -> None:
    """healthy.csv and faulty.csv in ``folder`` (made if missing, in a folder that exists); OSError if it cannot
    be written."""
    folder.mkdir(exist_ok=True)
    write_cycles_csv(folder / "healthy.csv", healthy, speed)
    write_cycles_csv(folder / "faulty.csv", faulty, speed)


def run(args: argparse.Namespace) -> int:
    try:
        if args.simulate:
            check_simulation(args)
            rng = np.random.default_rng(args.seed)
            load = None if args.load is None else (args.load[0], args.load[1])
            healthy, speed, _ = simulate_cycles(args.cycles, 0.0, tuple(args.temperature), rng, gravity=load)
            faulty, _, _ = simulate_cycles(args.cycles, args.wear, tuple(args.temperature), rng, gravity=load)
            if args.write_csv:
                try:
                    _write_csvs(args.write_csv, healthy, faulty, speed)
                except OSError as exc:
                    print(f"edge-monitor fit-weights: --write-csv: cannot write to {args.write_csv}: "
                          f"{exc.strerror or exc}", file=sys.stderr)
                    return EXIT_FAILURE
        else:
            if args.healthy is None or args.faulty is None:
                raise UsageError("give --healthy and --faulty CSV files, or --simulate")
            healthy, speed = read_cycles_csv(args.healthy)
            faulty, speed_f = read_cycles_csv(args.faulty)
            if speed_f.shape != speed.shape or not np.allclose(speed_f, speed, atol=0.05):
                raise CycleDataError("--healthy and --faulty must follow the same trajectory (speed per sample)")
        result = fit(healthy, faulty, speed, center=not args.no_center)
    except (CycleDataError, WeightFitError) as exc:
        print(f"edge-monitor fit-weights: {exc}", file=sys.stderr)
        return EXIT_USAGE
    result["source"] = "simulate" if args.simulate else {"healthy": str(args.healthy), "faulty": str(args.faulty)}
    text = json.dumps(result)
    if args.out:
        try:
            args.out.write_text(text + "\n")
        except OSError as exc:
            print(f"edge-monitor fit-weights: -o: cannot write {args.out}: {exc}", file=sys.stderr)
            return EXIT_FAILURE
        print(f"alpha={result['alpha']:.4g} beta={result['beta']:.4g} -> {args.out}")
    else:
        print(text)
    return 0
