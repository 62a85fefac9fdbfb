"""``edge-monitor evaluate``: compare detectors by simulation — design of experiments, second-order
surrogate models, SNR and scope matrices (docs/EVALUATION.md).

Every design point runs the simulator's default robot through the agent (nominal cycles at no wear,
then test cycles at the point's factor levels); per detector a second-order surrogate of q over the
coded factors gives the normalised coefficients, the SNR and the scope matrices. Output folder
(``--out``): PNG plots, ``evaluation.json`` (every number; ``--json`` also prints it) and ``REPORT.md``.
"""

from __future__ import annotations

import argparse
import logging
import os
import sys
from pathlib import Path

import numpy as np

from edge_monitor.config import ConfigError, load_config
from edge_monitor.offline.evaluation import factors as fa
from edge_monitor.offline.evaluation.design import (
    DesignError,
    central_composite,
    check_estimable,
    load_design_csv,
    validation_design,
)
from edge_monitor.offline.evaluation.detectors import DETECTORS, DetectorError, select_detectors
from edge_monitor.offline.evaluation.report import ReportError, require_matplotlib, write_report
from edge_monitor.offline.evaluation.runner import Settings, default_jobs, run_evaluation, run_replicated
from protocol.console import EXIT_FAILURE, UsageError, verbosity
from protocol.frames import MAX_JOINTS

log = logging.getLogger(__name__)

#: (test cycles, validation runs, scope draws) of a full and of a ``--quick`` evaluation.
FULL = (20, 12, 20_000)
QUICK = (4, 4, 4_000)
#: Upper bounds: more would not fit in memory (the Monte Carlo holds every draw) or the machine.
MAX_SNR_DRAWS = 1_000_000
MAX_SCOPE_DRAWS = 100_000
MAX_JOBS = 64
MAX_SEEDS = 20


def _names(text: str) -> list[str]:
    return [n.strip() for n in text.split(",") if n.strip()]


def add_parser(subparsers: argparse._SubParsersAction) -> argparse.ArgumentParser:
    parser = subparsers.add_parser(
        "evaluate", help="compare detectors by simulation: surrogate models, SNR, scope matrices",
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--factors", type=_names, default=None, metavar="NAME,...",
                        help=f"factors, fault first ({', '.join(fa.FACTORS)}); default: all "
                             f"({len(fa.DEFAULT_FACTORS)}), --quick: {','.join(fa.QUICK_FACTORS)}")
    parser.add_argument("--detectors", type=_names, default=list(DETECTORS), metavar="NAME,...",
                        help=f"detectors to compare (default: all: {', '.join(DETECTORS)})")
    parser.add_argument("--range", action="append", default=[], metavar="NAME=LOW:HIGH",
                        help="natural range of a factor (coded −2 … 2), e.g. temperature=35:65 (repeatable)")
    parser.add_argument("--design", type=Path, metavar="FILE.csv",
                        help="own design in coded levels (header: factor names) instead of the central composite")
    parser.add_argument("--validation", type=int, default=None, metavar="N",
                        help=f"validation runs on levels ±0.5, ±1.5 (default {FULL[1]}, --quick {QUICK[1]})")
    parser.add_argument("--test-cycles", type=int, default=None, metavar="N",
                        help=f"test cycles per design point; q is their mean (default {FULL[0]}, --quick {QUICK[0]})")
    parser.add_argument("--joint", type=int, default=0, help="monitored joint (default 0)")
    parser.add_argument("--joints", type=int, default=6, help="joints of the simulated robot (default 6)")
    parser.add_argument("--config", metavar="FILE", help="agent TOML config (default: embedded defaults)")
    parser.add_argument("--seed", type=int, default=1, help="seed of the robot, the test cycles and the Monte Carlo")
    parser.add_argument("--seeds", type=int, default=1, metavar="N",
                        help="replicate the evaluation for seeds SEED … SEED+N−1 and report the spread of SNR, "
                             "influences and dominant disturbance across them (default 1; N times the run time)")
    parser.add_argument("--jobs", type=int, default=default_jobs(), help="worker processes (default min(2, CPUs))")
    parser.add_argument("--snr-draws", type=int, default=100_000, help="Monte Carlo draws of the SNR")
    parser.add_argument("--scope-draws", type=int, default=None,
                        help=f"Monte Carlo draws per scope cell (default {FULL[2]}, --quick {QUICK[2]})")
    parser.add_argument("--noise", choices=("cycle", "mean", "none"), default="cycle",
                        help="spread of q in the SNR and scope Monte Carlo: one cycle's q (default), the mean of "
                             "the test cycles, or none (the surrogate alone)")
    parser.add_argument("--quick", action="store_true",
                        help="small design (3 factors, few cycles): a few minutes, for CI and trying it out")
    parser.add_argument("-o", "--out", type=Path, default=Path("evaluation"),
                        help="output folder (default ./evaluation)")
    parser.add_argument("--json", action="store_true", help="print the JSON of all numbers on stdout")
    parser.set_defaults(func=run)
    return parser


def _settings(args: argparse.Namespace) -> Settings:
    """Everything checked before any simulation; bad values raise :class:`UsageError`."""
    defaults = QUICK if args.quick else FULL
    names = args.factors if args.factors is not None else list(fa.QUICK_FACTORS if args.quick else fa.DEFAULT_FACTORS)
    try:
        ranges = dict(fa.parse_range_option(r) for r in args.range)
        factors = fa.select_factors(names, ranges)
        detectors = select_detectors(args.detectors)
    except (fa.FactorError, DetectorError) as exc:
        raise UsageError(str(exc)) from None
    if len(factors) < 2:
        raise UsageError("--factors: need the fault and at least one disturbance")
    checks = [
        (1 <= args.joints <= MAX_JOINTS, f"--joints must be 1 … {MAX_JOINTS}, got {args.joints}"),
        (0 <= args.joint < args.joints, f"--joint must be 0 … {args.joints - 1}, got {args.joint}"),
        (args.seed >= 0, f"--seed must be ≥ 0, got {args.seed}"),
        (1 <= args.seeds <= MAX_SEEDS, f"--seeds must be 1 … {MAX_SEEDS}, got {args.seeds}"),
        (1 <= args.jobs <= MAX_JOBS, f"--jobs must be 1 … {MAX_JOBS}, got {args.jobs}"),
        (args.test_cycles is None or args.test_cycles >= 2, f"--test-cycles must be ≥ 2, got {args.test_cycles}"),
        (args.validation is None or args.validation >= 0, f"--validation must be ≥ 0, got {args.validation}"),
        (1000 <= args.snr_draws <= MAX_SNR_DRAWS,
         f"--snr-draws must be 1000 … {MAX_SNR_DRAWS}, got {args.snr_draws}"),
        (args.scope_draws is None or 1000 <= args.scope_draws <= MAX_SCOPE_DRAWS,
         f"--scope-draws must be 1000 … {MAX_SCOPE_DRAWS}, got {args.scope_draws}"),
    ]
    for ok, message in checks:
        if not ok:
            raise UsageError(message)
    try:
        agent = load_config(args.config)
        design = load_design_csv(args.design, [f.name for f in factors]) if args.design else \
            central_composite(len(factors))
        check_estimable(design)
    except (ConfigError, DesignError) as exc:
        raise UsageError(str(exc)) from None
    n_validation = args.validation if args.validation is not None else defaults[1]
    if n_validation > 1 and n_validation % 4:
        log.warning("evaluate: --validation %d is not a multiple of 4: the levels ±0.5, ±1.5 are not used evenly",
                    n_validation)
    validation = validation_design(len(factors), n_validation, seed=args.seed)
    points = len(design) + len(validation)
    jobs = min(args.jobs, os.cpu_count() or 1, max(1, points))
    if jobs < args.jobs:
        log.info("evaluate: --jobs %d capped at %d (CPUs: %s, points: %d)", args.jobs, jobs, os.cpu_count(), points)
    return Settings(factors=tuple(factors), detectors=tuple(detectors), agent=agent, design=design,
                    validation=np.asarray(validation), joint=args.joint, joints=args.joints, seed=args.seed,
                    test_cycles=args.test_cycles if args.test_cycles is not None else defaults[0], jobs=jobs,
                    snr_draws=args.snr_draws,
                    scope_draws=args.scope_draws if args.scope_draws is not None else defaults[2], noise=args.noise,
                    design_name=f"own ({args.design.name})" if args.design else "central composite")


def run(args: argparse.Namespace) -> int:
    settings = _settings(args)
    if args.out.exists() and not args.out.is_dir():
        print(f"edge-monitor evaluate: --out: {args.out} is not a directory", file=sys.stderr)
        return EXIT_FAILURE
    try:
        require_matplotlib()
        args.out.mkdir(exist_ok=True)        # before the simulation: fail early; its parent must exist
    except ReportError as exc:
        print(f"edge-monitor evaluate: {exc}", file=sys.stderr)
        return EXIT_FAILURE
    except OSError as exc:
        print(f"edge-monitor evaluate: --out: cannot create {args.out}: {exc.strerror or exc}", file=sys.stderr)
        return EXIT_FAILURE
    log.info("evaluate: %d design + %d validation points, %d test cycles each, %d process(es), %d seed(s)",
             len(settings.design), len(settings.validation), settings.test_cycles, settings.jobs, args.seeds)
    result = (run_replicated(settings, args.seeds, progress=verbosity(args) >= 0) if args.seeds > 1 else
              run_evaluation(settings, progress=verbosity(args) >= 0))
    try:
        files = write_report(result, args.out)
    except ReportError as exc:
        print(f"edge-monitor evaluate: {exc}", file=sys.stderr)
        return EXIT_FAILURE
    if args.json:
        print(files["json"].read_text(encoding="utf-8"), end="")
    else:
        fnd = result["findings"]
        print(f"best SNR: {fnd['best_snr']}")
        if "replication" in result:
            rep = result["replication"]
            print(f"best SNR per seed {rep['seeds']}: {', '.join(str(b) for b in rep['best_snr'])}")
        for det, e in fnd["per_detector"].items():
            snr, fit = (None if x is None else round(x, 2) for x in (e["snr"], e["validation_fit"]))
            print(f"{det:16s} SNR {snr!s:>8}  validation fit {fit!s:>8} %  moved most by {e['dominant_disturbance']}")
        print(f"report: {files.get('report', args.out)}")
    return 0
