"""Checks of the files and folders a command is told to write: a typo never makes a directory tree, an
existing file is replaced only where the command says so, an input is never an output."""

from __future__ import annotations

import os
from pathlib import Path

from protocol.console import UsageError, same_file  # noqa: F401 (same_file: the commands' import)


def check_parent(path: str | Path, option: str) -> None:
    """UsageError (exit code 2) unless the folder ``path`` goes into exists."""
    parent = Path(path).parent
    if parent.exists() and not parent.is_dir():
        raise UsageError(f"{option} {path}: {parent} is a file, not a folder: fix the path")
    if not parent.is_dir():
        raise UsageError(f"{option} {path}: its folder {parent} does not exist: create it (mkdir -p {parent}) or "
                         "fix the path")


def check_output(path: str | Path, option: str, *, overwrite: bool) -> None:
    """UsageError unless ``path`` can be a new output: its folder exists, and it is not there yet (or
    ``overwrite``; never a directory)."""
    p = Path(path)
    try:
        check_parent(p, option)
        if p.is_dir():
            raise UsageError(f"{option} {p}: is a directory; give a file name")
        if os.path.lexists(p) and not overwrite:
            raise UsageError(f"{option} {p}: exists; pass --force to replace it, or choose another name")
    except OSError as exc:                   # a name too long, a path through a file, no permission to look
        raise UsageError(f"{option} {short_path(p)}: cannot be used as an output: {exc.strerror or exc}") from None


def name_too_long(path: str | Path) -> tuple[int, int] | None:
    """(bytes of the file name of ``path``, most its folder's file system takes) when the name is too long
    (NAME_MAX), else None."""
    p = Path(path)
    try:
        limit = os.pathconf(p.parent, "PC_NAME_MAX")
    except (OSError, ValueError):
        limit = 255
    size = len(os.fsencode(p.name))
    return (size, limit) if size > limit else None


def short_path(path: Path) -> str:
    """``path`` for a message: a very long one cut in its middle."""
    text = str(path)
    return text if len(text) <= 120 else f"{text[:60]}…{text[-50:]}"
