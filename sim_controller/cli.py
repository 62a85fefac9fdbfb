"""``sim-controller run | record``: the simulated robot controller on the command line.

Options given on the command line override a ``--scenario`` file; see docs/SIMULATOR.md.
Invalid input is refused with the subcommand's usage and a message naming the field (exit code 2);
a link or file that cannot be opened says which and why (exit code 1); Ctrl-C exits with 130.
SIGTERM ends ``run`` after the frame block being sent (the rest of it back to back), with the ground
truth and summary complete (exit code 0): a controller shut down in order. ``-v``/``-vv``/``-q`` work
before and after the subcommand (``protocol.console``).
"""

from __future__ import annotations

import os

# Before numpy loads: on a small edge box a threaded BLAS makes small products (~10⁴ elements) take
# milliseconds instead of microseconds when the other cores are busy (measured: 30 ms vs 10 µs).
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import argparse
import json
import logging
import signal
import sys
from pathlib import Path
from typing import Any, NoReturn, Sequence

from protocol import package_version
from protocol.console import (
    EXIT_CODES_HELP,
    EXIT_FAILURE,
    add_can_arguments,
    can_options,
    configure_logging,
    guarded_stdout,
    install_conventions,
    interrupted_exit,
    same_file,
    stdout_failure_exit,
    stop_on_signals,
    subcommands,
    verbosity,
)
from protocol.links import LinkError, LinkUsageError, is_log_file
from sim_controller.config import (
    SimConfig,
    SimConfigError,
    load_speeds_file,
    merge_wear,
    parse_float,
    parse_range,
    parse_speeds,
    wear_profiles_from_laws,
    wear_profiles_from_ramps,
)
from sim_controller.faults import FaultSpec
from sim_controller.output import DEFAULT_MAX_PAUSE_S, record, run
from sim_controller.scenario import load_scenario, packaged_scenarios
from sim_controller.timeline import merge_timelines, parse_event

log = logging.getLogger("sim_controller")


def _typed(parse: Any, name: str) -> Any:
    """argparse ``type=`` wrapper turning our ValueErrors into argparse errors naming ``name``."""
    def convert(text: str) -> Any:
        try:
            return parse(text)
        except ValueError as exc:
            raise argparse.ArgumentTypeError(str(exc)) from None
    convert.__name__ = name
    return convert


def _number(name: str, kind: type = float) -> Any:
    def parse(text: str) -> Any:
        if kind is int:
            try:
                return int(text)
            except ValueError:
                raise SimConfigError(f"{name}: expected an integer, got {text!r}") from None
        return parse_float(text, name)
    return _typed(parse, name)


def _add_common(p: argparse.ArgumentParser) -> None:
    g = p.add_argument_group("simulation")
    g.add_argument("--scenario", metavar="FILE.toml|NAME",
                   help="scenario file, or a packaged one by name (" + ", ".join(packaged_scenarios()) +
                        "); command-line options override it")
    g.add_argument("--event", action="append", default=[], type=_typed(parse_event, "event"),
                   metavar="CYCLE:KEY=VALUE[,KEY=VALUE]",
                   help="plant change at a test cycle (repeatable; added to the scenario's timeline): "
                        "load_range=LOW:HIGH, ambient=C, payload_error=F, load_std=S, stop_hours=H "
                        "(the robot stands still H hours before the cycle), e.g. 620:load_range=0.6:1.0")
    g.add_argument("--joints", type=_number("joints", int), help="number of joints 1 … 8 (default 6)")
    g.add_argument("--rate", type=_number("rate"), help="controller tick rate in Hz (default 500)")
    g.add_argument("--cycles", type=_number("cycles", int), help="number of test cycles (default 10)")
    g.add_argument("--seed", type=_number("seed", int), help="random seed (default 0); same seed, same output")
    sp = g.add_mutually_exclusive_group()
    sp.add_argument("--speeds", type=_typed(parse_speeds, "speeds"), metavar="V1,V2,...",
                    help="friction speed levels in rad/s (motor side; default: the 12 of docs/ALGORITHMS.md §2)")
    sp.add_argument("--speeds-from", metavar="DESIGN.json", help="speeds from the JSON of edge-monitor design")
    g.add_argument("--plateau-time", type=_number("plateau_time"),
                   help="constant-speed time per direction in s (default 1.1)")
    g.add_argument("--wear-ramp", action="append", default=[], metavar="JOINT:START:END:FROM:TO",
                   help="linear wear ramp (repeatable; JOINT 0-based or 'all'; wear 0 … 100)")
    g.add_argument("--wear-law", action="append", default=[], metavar="JOINT:KIND:KEY=VALUE,...",
                   help="wear event of any kind (repeatable, applied in order after the ramps; KIND ramp, "
                        "exponential, power, step or replacement; keys start, end, from, to, tau, exponent), "
                        "e.g. 2:power:start=100,end=900,from=0,to=60,exponent=2")
    g.add_argument("--temperature-range", type=_typed(lambda t: parse_range(t, "temperature_range"),
                   "temperature_range"),
                   metavar="LOW:HIGH", help="per-cycle uniform lubricant temperature in °C (default: thermal model)")
    g.add_argument("--ambient", type=_number("ambient"),
                   help="ambient temperature of the thermal model, °C (default 30)")
    g.add_argument("--start-temperature", type=_number("start_temperature"), help="initial lubricant temperature, °C")
    g.add_argument("--time-acceleration", type=_number("time_acceleration"),
                   help="thermal time runs this many times faster than controller time (default 1)")
    g.add_argument("--heating", type=_number("heating"),
                   help="thermal model: steady-state rise per unit mean friction power |τf·v|, °C (default 4)")
    g.add_argument("--load-range", type=_typed(lambda t: parse_range(t, "load_range"), "load_range"),
                   metavar="LOW:HIGH", help="per-cycle |load torque| range (default 0.3:0.7)")
    g.add_argument("--load-std", type=_number("load_std"), help="σl of the controller's load estimate (default 0.1)")
    g.add_argument("--friction-model-error", type=_number("friction_model_error"),
                   help="σm of the per-cycle, per-level friction model error (default 5.7e-3; 0 allowed)")
    g.add_argument("--torque-noise", type=_number("torque_noise"), help="per-sample torque noise std (default 2e-3)")
    g.add_argument("--speed-noise", type=_number("speed_noise"),
                   help="per-sample speed noise std in rad/s (default 0.02)")
    g.add_argument("--vary", type=_number("vary"), metavar="FRACTION",
                   help="± relative individual variation of friction parameters "
                        "(default 0 for 1 joint, 0.08 otherwise)")
    g.add_argument("--faults", type=_typed(FaultSpec.parse, "faults"), metavar="SPEC",
                   help="e.g. drop=0.001,corrupt=0.001,duplicate=0.0005,reorder=0.0005,delay=0.001,"
                        "silence=1e-5,restart=0.01,stuck=1e-5")
    g.add_argument("--start-time", type=_number("start_time"), metavar="S",
                   help="record: timestamp of tick 0 in s (default 0; e.g. a Unix time)")
    g.add_argument("--truth", metavar="PATH.jsonl",
                   help="write ground truth (one record per joint per cycle, then a fault summary)")
    g.add_argument("--json", dest="summary_json", action="store_true", help="print the run summary as JSON on stdout")
    g.add_argument("--summary-json", dest="summary_json", action="store_true", help=argparse.SUPPRESS)  # old name
    g.add_argument("--profile", default="native", metavar="native|cia402|dbc:MAPPING.toml",
                   help="whose frames to send: ours (default), CiA 402 drives (canopen TPDOs of the shipped "
                        "CiA 402 EDS) or a DBC mapping's (e.g. dbc:foreign_robot, a shipped mapping, or a "
                        "file); docs/CONNECTING.md")


_FIELD_OF_OPTION = {"joints": "joints", "rate": "rate", "cycles": "cycles", "seed": "seed", "speeds": "speeds",
                    "plateau_time": "plateau_time", "temperature_range": "temperature_range", "ambient": "ambient",
                    "start_temperature": "start_temperature", "time_acceleration": "time_acceleration",
                    "load_range": "load_range", "load_std": "load_std",
                    "friction_model_error": "friction_model_error", "torque_noise": "torque_noise",
                    "speed_noise": "speed_noise", "vary": "variation", "faults": "faults",
                    "heating": "heating", "start_time": "start_time"}


def build_config(args: argparse.Namespace) -> SimConfig:
    """SimConfig from scenario file + command-line options (raises SimConfigError)."""
    if args.joints is not None and not 1 <= args.joints <= 8:
        raise SimConfigError(f"joints: must be an integer 1 … 8, got {args.joints}")
    kwargs: dict[str, Any] = load_scenario(args.scenario, args.joints) if args.scenario else {}
    for option, name in _FIELD_OF_OPTION.items():
        value = getattr(args, option, None)
        if value is not None:
            kwargs[name] = value
    if args.speeds_from:
        kwargs["speeds"] = load_speeds_file(args.speeds_from)
    if kwargs.get("temperature_range") is not None:
        kwargs["min_temperature"] = min(kwargs.get("min_temperature", 30.0), kwargs["temperature_range"][0])
    joints = int(kwargs.get("joints", SimConfig.__dataclass_fields__["joints"].default))
    if not 1 <= joints <= 8:
        raise SimConfigError(f"joints: must be an integer 1 … 8, got {joints}")
    wear = kwargs.get("wear", ())
    if len(wear) > joints:
        wear = wear[:joints]
    if args.wear_ramp:
        wear = merge_wear(wear, wear_profiles_from_ramps(args.wear_ramp, joints), joints)
    if args.wear_law:
        wear = merge_wear(wear, wear_profiles_from_laws(args.wear_law, joints), joints)
    kwargs["wear"] = tuple(wear)
    overrides = kwargs.get("joint_overrides", ())
    kwargs["joint_overrides"] = tuple(overrides[:joints])
    kwargs["timeline"] = merge_timelines(kwargs.get("timeline", ()), args.event)
    return SimConfig(**kwargs)


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="sim-controller", description=__doc__.splitlines()[0])
    parser.add_argument("--version", action="version", version=f"%(prog)s {package_version()}")
    sub = parser.add_subparsers(dest="command", required=True)
    p_run = sub.add_parser("run", help="stream frames onto a link in real time or faster",
                           epilog=f"{EXIT_CODES_HELP}. SIGTERM ends a run after the frame block being sent: "
                                  "ground truth and summary complete, exit code 0")
    add_can_arguments(p_run, "slcan:DEVICE_OR_URL | socketcan:IFACE | virtual:NAME "
                             "(omit to use -i/-c/-b or python-can's CAN_*/~/.canrc config)")
    pace = p_run.add_mutually_exclusive_group()
    pace.add_argument("--realtime", action="store_true", help="pace at real time (default)")
    pace.add_argument("--speedup", type=_number("speedup"), metavar="X",
                      help="pace at X × real time; 0 = as fast as the link takes frames")
    p_run.add_argument("--max-pause", type=_number("max_pause"), metavar="S", default=DEFAULT_MAX_PAUSE_S,
                       help="longest wall-clock pause of a plant stop (--event …:stop_hours=H lasts H h / X); "
                            f"longer ones are cut to S seconds, with a log line (default {DEFAULT_MAX_PAUSE_S:g})")
    _add_common(p_run)
    p_rec = sub.add_parser("record", help="write frames to a python-can log file as fast as possible")
    p_rec.add_argument("-o", "--out", required=True, metavar="FILE.{blf,log,asc}",
                       help="log file (format from the suffix)")
    _add_common(p_rec)
    install_conventions(parser)
    return parser


def _run_option_error(args: argparse.Namespace) -> str | None:
    """What is wrong with the options of ``run`` beyond their syntax, or None."""
    if args.speedup is not None and args.speedup < 0:
        return f"speedup: must be ≥ 0, got {args.speedup}"
    if args.max_pause < 0:
        return f"max_pause: must be ≥ 0 s, got {args.max_pause}"
    if is_log_file(args.link):
        return f"--link {args.link} is a log file; use `sim-controller record --out {args.link}`"
    return None


def _truth_error(truth: str | None) -> str | None:
    """What is wrong with ``--truth PATH`` as a file to write (a directory, a folder that does not exist or is a
    file), or None: found before anything is simulated or written."""
    if not truth:
        return None
    path = Path(truth)
    try:
        if path.is_dir():
            return f"--truth {truth}: is a directory; give a file name (e.g. {path / 'truth.jsonl'})"
        if path.parent.exists() and not path.parent.is_dir():
            return f"--truth {truth}: {path.parent} is a file, not a folder: fix the path"
        if not path.parent.is_dir():
            return (f"--truth {truth}: its folder {path.parent} does not exist: create it (mkdir -p {path.parent}) "
                    "or fix the path")
    except OSError as exc:          # a name too long, a folder not readable: stat itself fails
        return f"--truth {truth}: cannot be checked ({exc.strerror or exc}): fix the path"
    return None


def _encoder(args: argparse.Namespace, config: SimConfig) -> Any:
    """The frame encoder of ``--profile`` (None: our frames)."""
    if args.profile == "native":
        return None
    if config.faults.any_link_fault:
        raise SimConfigError("faults: link faults are simulated for --profile native only")
    from sim_controller.profiles import profile_encoder
    return profile_encoder(args.profile, config.joints, config.start_time, config.rate)


def main(argv: Sequence[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    configure_logging(verbosity(args))
    command_parser = subcommands(parser)[args.command]

    def usage_error(message: str) -> NoReturn:
        command_parser.error(message)   # the subcommand's usage and the message, exit 2

    try:
        config = build_config(args)
    except ValueError as exc:   # SimConfigError, WearScenarioError, FaultSpecError, FrictionParams errors
        usage_error(str(exc))
    log.info("%s: %d joints, %d cycles at %g Hz, seed %d -> %s", args.command, config.joints, config.cycles,
             config.rate, config.seed, getattr(args, "out", None) or args.link or "python-can configuration")
    if (problem := _truth_error(args.truth)) is not None:
        usage_error(problem)
    try:
        encoder = _encoder(args, config)
    except ValueError as exc:     # ProfileError, MappingError, BitFieldError, Cia402Error
        usage_error(str(exc))
    try:
        if args.command == "record":
            if args.truth and same_file(Path(args.truth), Path(args.out)):
                usage_error(f"--truth {args.truth} is the log --out: give the truth file another name")
            summary = record(config, args.out, args.truth, progress=verbosity(args) >= 0, encoder=encoder)
        else:                               # SIGTERM: its normal end (stop after the current block)
            if (problem := _run_option_error(args)) is not None:
                usage_error(problem)
            speedup = None if args.speedup == 0 else (args.speedup or 1.0)
            stop = stop_on_signals((signal.SIGTERM,), "stopping after the current frame block")
            summary = run(config, args.link, speedup=speedup, truth_path=args.truth, bus_kwargs=can_options(args),
                          stop=stop.is_set, max_pause=args.max_pause, encoder=encoder)
    except LinkUsageError as exc:        # a bad link, interface or log suffix, no CAN configured: exit 2
        usage_error(str(exc))
    except (LinkError, OSError) as exc:
        print(f"sim-controller: {exc}", file=sys.stderr)
        return EXIT_FAILURE
    except KeyboardInterrupt as exc:
        return interrupted_exit(f"sim-controller {args.command}", exc)
    if args.summary_json:
        try:
            with guarded_stdout():
                print(json.dumps(summary.to_dict()))
        except OSError as exc:           # > /dev/full, a full disk: one line, exit 1 (the log itself is written)
            code = stdout_failure_exit(f"sim-controller {args.command}", exc)
            if code is None:
                raise
            return code
    elif verbosity(args) >= 0:
        print(f"sim-controller {args.command}: {summary.frames_sent} frames, {summary.cycles} cycles, "
              f"{summary.simulated_s:.1f} s simulated in {summary.wall_s:.2f} s "
              f"({summary.speed_ratio:.1f}× real time)", file=sys.stderr)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
