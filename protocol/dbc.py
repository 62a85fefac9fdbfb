"""The packaged DBC file (protocol/dbc/robot_joints.dbc), loaded with cantools."""

from __future__ import annotations

from importlib import resources
from pathlib import Path

import cantools

DBC_RESOURCE = "robot_joints.dbc"


def dbc_text() -> str:
    """Text of the packaged DBC file."""
    try:
        return resources.files("protocol").joinpath("dbc", DBC_RESOURCE).read_text(encoding="utf-8")
    except (NotADirectoryError, FileNotFoundError, TypeError):
        # setuptools' editable finder can present `protocol` as a namespace package whose path
        # holds a non-directory placeholder, which importlib.resources (3.11) rejects.
        return (Path(__file__).resolve().parent / "dbc" / DBC_RESOURCE).read_text(encoding="utf-8")


def load_database() -> cantools.database.can.Database:
    """The frame catalogue as a cantools database (strict: overlapping/oversized signals raise)."""
    return cantools.database.load_string(dbc_text(), database_format="dbc", strict=True)
