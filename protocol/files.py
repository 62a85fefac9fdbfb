"""Files given by a user or left on disk are untrusted: read only regular files, and never more than
a stated size (a leaf module: it imports nothing of the project; the agent and the mapping, DBC and EDS
readers use it).

A path may name a FIFO (opening it for reading blocks until a writer comes), a device (``/dev/zero``
and ``/dev/urandom`` never end, ``/dev/full`` refuses every write), a directory or a socket, directly
or through a symlink. :func:`open_regular` opens without blocking and checks what was opened, so
there is no window between the check and the use; :func:`read_regular` reads at most a cap.
"""

from __future__ import annotations

import os
import stat
from collections.abc import Callable
from pathlib import Path

_NO_BLOCK = os.O_NONBLOCK | getattr(os, "O_CLOEXEC", 0)


class NotARegularFile(ValueError):
    """A path that should name a regular file names something else (or one too large to read);
    ``reason`` says what, without the path ("it is a FIFO, not a regular file")."""

    def __init__(self, path: str | os.PathLike[str], reason: str) -> None:
        super().__init__(f"{path}: {reason}")
        self.path, self.reason = str(path), reason


def file_kind(mode: int) -> str:
    """What a file of ``mode`` (``st_mode``) is, in words ("a regular file", "a FIFO", …)."""
    for test, name in ((stat.S_ISREG, "a regular file"), (stat.S_ISDIR, "a directory"), (stat.S_ISFIFO, "a FIFO"),
                       (stat.S_ISCHR, "a character device"), (stat.S_ISBLK, "a block device"),
                       (stat.S_ISSOCK, "a socket")):
        if test(mode):
            return name
    return "not a regular file"


def open_regular(path: str | os.PathLike[str], flags: int = os.O_RDONLY, mode: int = 0o644) -> int:
    """A file descriptor of ``path`` opened with ``flags`` (never blocking on a FIFO) if it is a
    regular file; :class:`NotARegularFile` naming what it is otherwise, ``OSError`` if it cannot be
    opened. The descriptor is blocking again for regular files (O_NONBLOCK does nothing there)."""
    fd = os.open(path, flags | _NO_BLOCK, mode)
    try:
        kind = os.fstat(fd).st_mode
        if not stat.S_ISREG(kind):
            raise NotARegularFile(path, f"it is {file_kind(kind)}, not a regular file")
    except BaseException:
        os.close(fd)
        raise
    return fd


def read_regular(path: str | os.PathLike[str], max_bytes: int) -> bytes:
    """The bytes of the regular file ``path`` if it holds at most ``max_bytes`` (also if it grows
    while read); :class:`NotARegularFile` otherwise, ``OSError`` if it cannot be opened or read."""
    fd = open_regular(path)
    try:
        size = os.fstat(fd).st_size
        if size > max_bytes:
            raise NotARegularFile(path, f"it has {size} bytes, more than the {max_bytes} it may have")
        chunks, total = [], 0
        while total <= max_bytes:
            chunk = os.read(fd, min(1 << 20, max_bytes + 1 - total))
            if not chunk:
                break
            chunks.append(chunk)
            total += len(chunk)
        if total > max_bytes:
            raise NotARegularFile(path, f"it grew past the {max_bytes} bytes it may have while it was read")
        return b"".join(chunks)
    finally:
        os.close(fd)


def read_regular_or(path: str | os.PathLike[str], max_bytes: int, what: str,
                    invalid: Callable[[str], Exception], unreadable: Callable[[str], Exception]) -> bytes:
    """:func:`read_regular`, its failures raised as the caller's errors with ``what`` (e.g. "mapping
    file") naming the file: ``invalid`` for one that is missing, too large or not a regular file (bad
    input), ``unreadable`` for an I/O error."""
    try:
        return read_regular(path, max_bytes)
    except FileNotFoundError:
        raise invalid(f"{what} {path} not found") from None
    except NotARegularFile as exc:
        raise invalid(f"{what} {path}: {exc.reason}") from None
    except IsADirectoryError:
        raise invalid(f"{what} {path}: it is a directory, not a regular file") from None
    except OSError as exc:
        raise unreadable(f"{what} {path} cannot be read: {exc.strerror or exc}") from None


def require_regular(path: str | os.PathLike[str]) -> Path:
    """``path`` if it names a regular file (following symlinks); :class:`NotARegularFile` if it names
    something else, ``FileNotFoundError`` if nothing. For readers that open the file themselves."""
    p = Path(path)
    kind = p.stat().st_mode
    if not stat.S_ISREG(kind):
        raise NotARegularFile(p, f"it is {file_kind(kind)}, not a regular file")
    return p
