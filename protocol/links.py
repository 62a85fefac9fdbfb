"""Links: open a python-can bus from a link string, log files, a bridged pty pair, vcan detection.

Link strings (docs/PROTOCOL.md, "Links"):

* ``socketcan:IFACE``            Linux SocketCAN (real or vcan)
* ``slcan:DEVICE_OR_URL``        Lawicel serial-line CAN over a serial device, a pty or any pyserial
                                 URL such as ``socket://127.0.0.1:PORT``
* ``virtual:NAME``               python-can in-process bus (one process only)
* ``None``                       python-can's own configuration (arguments, ``CAN_*`` environment,
                                 ``~/.canrc``); none of them naming an interface raises ``NoCanConfigError``
* a log file (``.blf``, ``.log``, ``.asc``, ``.csv``, ``.trc``) is not a bus: see ``is_log_file``.
"""

from __future__ import annotations

import errno
import logging
import os
import socket
from pathlib import Path
from typing import Any, Iterable

import can

from protocol.pty_pair import PtyObserver, PtyPair

__all__ = ["LINK_SCHEMES", "LOG_SUFFIXES", "NO_CAN_CONFIG", "LinkError", "LinkUsageError",
           "NoCanConfigError", "PtyObserver", "PtyPair",
           "is_log_file", "open_bus", "open_log_reader", "open_log_writer", "parse_link", "vcan_available"]

log = logging.getLogger(__name__)

LOG_SUFFIXES = (".blf", ".log", ".asc", ".csv", ".trc", ".log.gz", ".asc.gz")
LINK_SCHEMES = ("socketcan", "slcan", "virtual")


class LinkError(ValueError):
    """A link could not be opened or is malformed; the message starts with the link."""


class LinkUsageError(LinkError):
    """A link, interface name or log file name that cannot be right (a usage error, exit code 2), as
    opposed to a valid one that fails to open (a runtime failure, exit code 1)."""


class NoCanConfigError(LinkUsageError):
    """No link given and python-can's configuration names no interface: the message says what to do."""


NO_CAN_CONFIG = ("no CAN interface configured: pass --link socketcan:IFACE or slcan:/dev/pts/N, -i/--interface "
                 "with -c/--channel, or set CAN_INTERFACE/CAN_CHANNEL or a python-can config file (~/.canrc)")


def is_log_file(link: str | os.PathLike | None) -> bool:
    """True if ``link`` names a CAN log file by its suffix (it need not exist yet)."""
    if link is None:
        return False
    name = str(link).lower()
    if name.split(":", 1)[0] in LINK_SCHEMES:
        return False
    return name.endswith(LOG_SUFFIXES)


def open_log_reader(path: str | os.PathLike) -> Iterable[can.Message]:
    """python-can LogReader for an existing log file (format from the suffix)."""
    if not is_log_file(path):
        raise LinkUsageError(f"{path}: not a CAN log file; use one of {', '.join(LOG_SUFFIXES)}")
    if not Path(path).is_file():
        raise LinkError(f"{path}: log file not found")
    try:
        return can.LogReader(path)
    except Exception as error:  # noqa: BLE001 - re-raised as the typed error
        raise LinkError(f"{path}: cannot read log ({error})") from error


def open_log_writer(path: str | os.PathLike) -> can.Listener:
    """python-can Logger writing a log file (format from the suffix); call ``.stop()`` to close."""
    if not is_log_file(path):
        raise LinkUsageError(f"{path}: not a CAN log file; use one of {', '.join(LOG_SUFFIXES)}")
    try:
        return can.Logger(path)
    except Exception as error:  # noqa: BLE001
        raise LinkError(f"{path}: cannot write log ({error})") from error


def parse_link(link: str) -> tuple[str, str]:
    """``"scheme:channel"`` -> (scheme, channel); raises LinkError naming the link."""
    scheme, sep, channel = str(link).partition(":")
    if not sep or scheme not in LINK_SCHEMES:
        raise LinkUsageError(f"{link}: unknown link; use socketcan:IFACE, slcan:DEVICE_OR_URL, virtual:NAME "
                             "or a log file")
    if not channel:
        raise LinkUsageError(f"{link}: missing channel after '{scheme}:'")
    return scheme, channel


def open_bus(
    link: str | None,
    *,
    interface: str | None = None,
    channel: str | None = None,
    bitrate: int | None = None,
    receive_own_messages: bool = False,
    **kwargs: Any,
) -> can.BusABC:
    """Open a python-can bus from a link string (or python-can's configuration if ``link`` is None).

    Extra keyword arguments go to the python-can interface (e.g. ``sleep_after_open`` for slcan,
    default 0 here).  Failures raise ``LinkError`` saying which link and why.
    """
    if link is None:
        return _open_configured(interface, channel, bitrate, receive_own_messages, kwargs)
    if is_log_file(link):
        raise LinkUsageError(f"{link}: a log file is not a bus; read it with open_log_reader()")
    scheme, target = parse_link(link)
    options: dict[str, Any] = dict(kwargs)
    if bitrate is not None:
        options["bitrate"] = bitrate
    if scheme == "slcan":
        options.setdefault("sleep_after_open", 0)
        if "://" not in target and not target.split("@", 1)[0].startswith("COM") \
                and not os.path.exists(target.split("@", 1)[0]):
            raise LinkError(f"{link}: device not found")
    else:
        options["receive_own_messages"] = receive_own_messages
    try:
        if scheme == "slcan":   # chunked reads: python-can's byte-wise reader starves next to numeric threads
            from protocol.slcan_fast import FastSlcanBus
            return FastSlcanBus(target, **options)
        return can.Bus(interface=scheme, channel=target, ignore_config=True, **options)
    except Exception as error:  # noqa: BLE001 - every interface raises its own types
        raise LinkError(f"{link}: {_reason(error)}") from error


def _open_configured(
    interface: str | None, channel: str | None, bitrate: int | None, receive_own_messages: bool,
    kwargs: dict[str, Any],
) -> can.BusABC:
    options: dict[str, Any] = dict(kwargs)
    for key, value in (("interface", interface), ("channel", channel), ("bitrate", bitrate)):
        if value is not None:
            options[key] = value
    if receive_own_messages:
        options["receive_own_messages"] = True
    described = f"interface={interface or '(config)'} channel={channel or '(config)'}"
    if interface is None and not _interface_configured(options.get("config_context")):
        raise NoCanConfigError(NO_CAN_CONFIG)
    if interface is not None and interface not in can.interfaces.VALID_INTERFACES:
        raise LinkUsageError(f"--interface {interface}: not a python-can interface; use one of "
                             f"{', '.join(sorted(can.interfaces.VALID_INTERFACES))}")
    try:
        config = can.util.load_config(config={k: v for k, v in options.items()
                                              if k in ("interface", "channel", "bitrate")},
                                      context=options.get("config_context"))
    except Exception as error:  # noqa: BLE001
        raise LinkError(f"{described}: python-can configuration invalid ({_reason(error)})") from error
    if config.get("interface") == "slcan":
        options.setdefault("sleep_after_open", 0)
    try:
        return can.Bus(**options)
    except Exception as error:  # noqa: BLE001
        raise LinkError(f"{described}: {_reason(error)}; set --interface/--channel, CAN_INTERFACE/"
                        "CAN_CHANNEL or ~/.canrc") from error


def _interface_configured(context: str | None) -> bool:
    """Whether python-can's configuration chain (``can.rc``, ``CAN_*`` environment, config files)
    names an interface; when unsure, True (python-can then says what is wrong)."""
    try:
        sources = [can.rc, can.util.load_environment_config(context), can.util.load_environment_config(),
                   can.util.load_file_config(None, context) if context else {}, can.util.load_file_config()]
    except Exception:  # noqa: BLE001 - e.g. CAN_CONFIG not JSON: python-can reports it
        return True
    return any(source.get("interface") or source.get("bustype") for source in sources)


def _reason(error: BaseException) -> str:
    if isinstance(error, FileNotFoundError) or getattr(error, "errno", None) == errno.ENOENT:
        return f"device not found ({error})"
    if isinstance(error, OSError) and error.errno == errno.EAFNOSUPPORT:
        return f"SocketCAN is not supported by this kernel ({error})"
    if isinstance(error, OSError) and error.errno == errno.ENODEV:
        return f"no such network interface ({error})"
    return f"{type(error).__name__}: {error}"


def vcan_available(name: str = "vcan0") -> bool:
    """True if the SocketCAN interface ``name`` exists and a raw CAN socket can bind to it."""
    try:
        if not Path("/sys/class/net", name).exists():
            return False
        with socket.socket(socket.AF_CAN, socket.SOCK_RAW, socket.CAN_RAW) as sock:
            sock.bind((name,))
        return True
    except Exception:  # noqa: BLE001 - detection never raises
        return False

