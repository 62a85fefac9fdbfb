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
    check_parent(p, option)
    if p.is_dir():
        raise UsageError(f"{option} {p}: is a directory; give a file name")
    if os.path.lexists(p) and not overwrite:
        raise UsageError(f"{option} {p}: exists; pass --force to replace it, or choose another name")
