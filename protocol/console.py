"""Conventions shared by the command-line tools ``edge-monitor`` and ``sim-controller``.

One place for what a CAN user expects of both: ``-v``/``-vv``/``-q`` before or after the subcommand
(default: warnings only), documented exit codes, python-can's ``-i/-c/-b`` options with its
configuration chain, and progress bars on stderr that show only on a terminal.
"""

from __future__ import annotations

import argparse
import logging
import os
import re
import signal
import sys
import threading
from contextlib import contextmanager
from pathlib import Path
from typing import Any, Iterator, TextIO

from tqdm import tqdm
from tqdm.contrib.logging import logging_redirect_tqdm

EXIT_OK = 0
#: A CAN link or log file cannot be opened, read or written, an output cannot be written, the link failed.
EXIT_FAILURE = 1
#: Bad arguments or option values, invalid input/settings files, no CAN interface configured.
EXIT_USAGE = 2
#: Interrupted with Ctrl-C before the work was done.
EXIT_INTERRUPTED = 130
#: Terminated by SIGTERM before the work was done (a command that runs until stopped ends with 0 instead).
EXIT_TERMINATED = 143

EXIT_CODES_HELP = (
    "exit codes: 0 ok; 1 runtime failure (a CAN link, log or output file cannot be opened, read or written, "
    "or the link failed); 2 usage error (bad arguments or values, invalid input or settings file, no CAN "
    "interface configured); 130 interrupted (Ctrl-C); 143 terminated (SIGTERM) before the work was done")

#: Said once under any help that cites docs/: a wheel installs none of them.
DOCS_NOTE = ("docs/…: the project's documentation, in its source repository (a wheel installs none of it); "
             "record schemas: edge-monitor schema KIND; service files and example mappings: edge-monitor deploy "
             "--list")

LOG_FORMAT = "%(asctime)s %(levelname)s %(name)s: %(message)s"

log = logging.getLogger(__name__)


class UsageError(ValueError):
    """Bad arguments or option values: reported with the subcommand's usage, exit code 2."""


def add_verbosity_arguments(parser: argparse.ArgumentParser, *, after_command: bool = False) -> None:
    """``-v``/``--verbose`` (repeatable) and ``-q``/``--quiet``; separate destinations after the
    subcommand, so that ``-v run -v`` counts both."""
    suffix = "_after" if after_command else ""
    parser.add_argument("-v", "--verbose", action="count", default=0, dest="verbose" + suffix,
                        help="more log output: -v info (status lines), -vv debug")
    parser.add_argument("-q", "--quiet", action="count", default=0, dest="quiet" + suffix,
                        help="errors only: no warnings, summary lines or progress bar")


class UserHelpFormatter(argparse.RawDescriptionHelpFormatter):
    """Help for users: the description keeps its paragraphs and examples; an option that stores a value
    shows its default when it has a meaningful one (not None, not already said in its help)."""

    def _get_help_string(self, action: argparse.Action) -> str | None:
        text = action.help or ""
        meaningful = action.default not in (None, "", []) and action.default is not argparse.SUPPRESS
        if (type(action) is argparse._StoreAction and action.option_strings and meaningful
                and not action.required and "default" not in text):
            return f"{text} (default: %(default)s)"
        return text


_ROLE = re.compile(r":(?:mod|class|func|meth|data|attr):`~?([^`]+)`")


def user_text(text: str | None) -> str | None:
    """A docstring as help text: no reST markup (``code``, :role:`target`)."""
    if text is None:
        return None
    return _ROLE.sub(lambda m: m.group(1).rsplit(".", 1)[-1], text).replace("``", "")


def library_message(exc: BaseException, limit: int = 300) -> str:
    """The first line of a library's exception text, at most ``limit`` characters, without a closing full
    stop, control characters shown as ``?``: one line of a file's diagnosis (pyarrow, cantools and canopen
    quote file contents and add lines of context)."""
    first = (str(exc).strip().splitlines() or [""])[0][:limit].rstrip(".")
    return "".join(c if c.isprintable() else "?" for c in first)


def subcommands(parser: argparse.ArgumentParser) -> dict[str, argparse.ArgumentParser]:
    """The subcommand parsers of ``parser`` by name (empty without subcommands)."""
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            return dict(action.choices)
    return {}


def install_conventions(parser: argparse.ArgumentParser) -> None:
    """Verbosity options on ``parser`` and on every subcommand, exit codes in every ``--help``."""
    parser.epilog = parser.epilog or EXIT_CODES_HELP
    add_verbosity_arguments(parser)
    for p in (parser, *subcommands(parser).values()):
        p.formatter_class = UserHelpFormatter
        p.description = user_text(p.description)
    for sub in subcommands(parser).values():
        add_verbosity_arguments(sub, after_command=True)
        sub.epilog = sub.epilog or EXIT_CODES_HELP
    for p in (parser, *subcommands(parser).values()):
        if _cites_docs(p):
            p.epilog = f"{p.epilog}\n\n{DOCS_NOTE}"


def _cites_docs(parser: argparse.ArgumentParser) -> bool:
    texts = [parser.description or "", parser.epilog or ""]
    texts += [a.help or "" for a in parser._actions] + [g.description or "" for g in parser._action_groups]
    return any("docs/" in t for t in texts)


def verbosity(args: argparse.Namespace) -> int:
    """-1 quiet, 0 default, 1 info, 2 debug (``-v``/``-q`` before and after the subcommand add up)."""
    loud = getattr(args, "verbose", 0) + getattr(args, "verbose_after", 0)
    quiet = getattr(args, "quiet", 0) + getattr(args, "quiet_after", 0)
    return max(-1, min(2, loud - quiet))


def configure_logging(level_of_detail: int) -> None:
    """Root logging at ERROR (-1), WARNING (0), INFO (1) or DEBUG (2), to stderr."""
    level = {-1: logging.ERROR, 0: logging.WARNING, 1: logging.INFO}.get(level_of_detail, logging.DEBUG)
    logging.basicConfig(level=level, format=LOG_FORMAT)
    logging.getLogger().setLevel(level)


def usage_error(parser: argparse.ArgumentParser, message: str) -> int:
    """What ``parser.error`` prints (usage and message on stderr), returning the exit code instead of exiting."""
    parser.print_usage(sys.stderr)
    print(f"{parser.prog}: error: {message}", file=sys.stderr)
    return EXIT_USAGE


class Terminated(KeyboardInterrupt):
    """SIGTERM arrived: raised where Ctrl-C's KeyboardInterrupt would be, so the same clean-up runs."""


def _raise_terminated(signum: int, _frame: Any) -> None:
    raise Terminated(f"signal {signum}")


@contextmanager
def terminate_like_interrupt() -> Iterator[None]:
    """Within the block SIGTERM takes Ctrl-C's path (:class:`Terminated`: worker processes stopped, outputs
    closed, a message, exit code 143) instead of Python's default, which kills the process at once and
    leaves its workers and their semaphores behind. A command that runs until stopped installs its own
    handler over this one. Outside the main thread signals cannot be caught: nothing changes there."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    previous = signal.signal(signal.SIGTERM, _raise_terminated)
    try:
        yield
    finally:
        signal.signal(signal.SIGTERM, previous)


def interrupted_exit(command: str, exc: KeyboardInterrupt) -> int:
    """Say that ``command`` was interrupted or terminated, on stderr; the exit code for it."""
    if isinstance(exc, Terminated):
        print(f"{command}: terminated (SIGTERM)", file=sys.stderr)
        return EXIT_TERMINATED
    print(f"{command}: interrupted", file=sys.stderr)
    return EXIT_INTERRUPTED


class _StdoutGuard:
    """``sys.stdout`` while a command runs (:func:`guarded_stdout`): a write or flush that fails is marked
    (``on_stdout``) so that :func:`stdout_failure_exit` tells it from the command's other I/O errors."""

    def __init__(self, stream: TextIO) -> None:
        self._stream = stream

    def write(self, text: str) -> int:
        try:
            return self._stream.write(text)
        except OSError as exc:
            exc.on_stdout = True  # type: ignore[attr-defined]
            raise

    def flush(self) -> None:
        try:
            self._stream.flush()
        except OSError as exc:
            exc.on_stdout = True  # type: ignore[attr-defined]
            raise

    def __getattr__(self, name: str) -> Any:
        return getattr(self._stream, name)


@contextmanager
def guarded_stdout() -> Iterator[None]:
    """Within the block a failed write to standard output (``> /dev/full``, a full disk, ``| head`` gone) raises
    an ``OSError`` marked for :func:`stdout_failure_exit`; the output is flushed at the block's end, inside it."""
    original = sys.stdout
    if original is None:
        yield
        return
    sys.stdout = _StdoutGuard(original)
    try:
        yield
        if not original.closed:
            sys.stdout.flush()
    finally:
        sys.stdout = original


def stdout_failure_exit(command: str, exc: OSError) -> int | None:
    """The exit code for a failed write to standard output, None for any other ``OSError``. A reader that went
    away (``| head``) is a normal end (0, quiet); any other failure (``ENOSPC``, ``EIO``) says that the output is
    incomplete (exit 1). What could not be written is dropped, so that Python's exit does not fail on it again."""
    if not getattr(exc, "on_stdout", False):
        return None
    try:
        devnull = os.open(os.devnull, os.O_WRONLY)
        os.dup2(devnull, sys.stdout.fileno())
        os.close(devnull)
    except (OSError, ValueError, AttributeError):
        pass                                  # no file descriptor (a test's capture): nothing left to fail
    if isinstance(exc, BrokenPipeError):
        return EXIT_OK
    print(f"{command}: cannot write to standard output ({exc.strerror or exc}): the output is incomplete; "
          "redirect it to a file on a disk with space, or to a pipe that reads it", file=sys.stderr)
    return EXIT_FAILURE


class DeferredInterrupt:
    """Ctrl-C or SIGTERM noted, not raised (:func:`deferred_interrupts`): ``pending`` is what to raise."""

    def __init__(self) -> None:
        self.pending: KeyboardInterrupt | None = None

    def note(self, signum: int, _frame: Any) -> None:
        if self.pending is None:
            log.warning("signal %d: stopping after the current block", signum)
        self.pending = Terminated(f"signal {signum}") if signum == signal.SIGTERM else KeyboardInterrupt()


@contextmanager
def deferred_interrupts() -> Iterator[DeferredInterrupt]:
    """Within the block, Ctrl-C and SIGTERM are noted instead of raised, so that a writer is never cut
    mid-container (a BLF file so cut cannot be read back); the loop checks ``pending``, ends, closes its
    outputs and raises it. Outside the main thread signals cannot be caught: nothing changes there."""
    deferred = DeferredInterrupt()
    if threading.current_thread() is not threading.main_thread():
        yield deferred
        return
    previous = {signum: signal.signal(signum, deferred.note) for signum in (signal.SIGINT, signal.SIGTERM)}
    try:
        yield deferred
    finally:
        for signum, handler in previous.items():
            signal.signal(signum, handler)


def same_file(a: Path, b: Path) -> bool:
    """Whether ``a`` and ``b`` name one file (the same inode, or the same resolved path if one is missing)."""
    try:
        return os.path.samefile(a, b)
    except OSError:
        return a.resolve() == b.resolve()


def stop_on_signals(signums: tuple[int, ...] = (signal.SIGINT, signal.SIGTERM), say: str = "") -> threading.Event:
    """An event set by any of ``signums`` (the normal end of a command that runs until stopped), with
    ``say`` logged as a warning when it comes (e.g. what the command does before it ends)."""
    stop = threading.Event()

    def handler(signum: int, _frame: Any) -> None:
        if say and not stop.is_set():
            log.warning("signal %d: %s", signum, say)
        stop.set()
    if threading.current_thread() is threading.main_thread():
        for signum in signums:
            signal.signal(signum, handler)
    return stop


def add_can_arguments(parser: argparse.ArgumentParser, link_help: str) -> None:
    """``--link`` and python-can's ``-i/--interface``, ``-c/--channel``, ``-b/--bitrate``."""
    group = parser.add_argument_group(
        "CAN link", "--link, or python-can's configuration: -i/-c/-b, else CAN_INTERFACE/CAN_CHANNEL/CAN_BITRATE, "
                    "else a config file (~/.canrc, ~/can.conf, /etc/can.conf)")
    group.add_argument("--link", help=link_help)
    group.add_argument("-i", "--interface", help="python-can interface, e.g. socketcan, slcan, pcan (without --link)")
    group.add_argument("-c", "--channel", help="python-can channel, e.g. can0 or /dev/ttyACM0 (without --link)")
    group.add_argument("-b", "--bitrate", type=int, help="CAN bitrate in bit/s")


def can_options(args: argparse.Namespace) -> dict[str, Any]:
    """The ``-i/-c/-b`` values given, as keyword arguments of ``protocol.links.open_bus``."""
    return {k: getattr(args, k) for k in ("interface", "channel", "bitrate") if getattr(args, k, None) is not None}


def _fallback_size(stream: TextIO) -> dict[str, int]:
    """A terminal reporting no size (serial console, bare pty) would hide the bar: assume 80×24 there."""
    try:
        size = os.get_terminal_size(stream.fileno())
    except (AttributeError, OSError, ValueError):
        return {}
    return {} if size.columns and size.lines else {"ncols": size.columns or 80, "nrows": size.lines or 24}


@contextmanager
def progress_bar(total: float | None, desc: str, *, enabled: bool = True, **options: Any) -> Iterator[tqdm]:
    """A tqdm bar on stderr, shown only when stderr is a terminal and ``enabled`` (off with ``-q``);
    log records go around it while it shows. ``bar.disable`` tells whether it shows."""
    bar = tqdm(total=total, desc=desc, file=sys.stderr, disable=None if enabled else True, leave=False,
               **_fallback_size(sys.stderr), **options)
    try:
        if bar.disable:
            yield bar
        else:
            with logging_redirect_tqdm():
                yield bar
    finally:
        bar.close()
