"""The packaged DBC file (protocol/dbc/robot_joints.dbc), loaded with cantools."""

from __future__ import annotations

from importlib import resources

import cantools

DBC_RESOURCE = "robot_joints.dbc"


def dbc_text() -> str:
    """Text of the packaged DBC file."""
    return resources.files("protocol").joinpath("dbc", DBC_RESOURCE).read_text(encoding="utf-8")


def load_database() -> cantools.database.Database:
    """The frame catalogue as a cantools database (strict: overlapping/oversized signals raise)."""
    return cantools.database.load_string(dbc_text(), database_format="dbc", strict=True)
