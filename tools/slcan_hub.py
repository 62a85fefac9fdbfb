#!/usr/bin/env python3
"""Thin wrapper kept for old scripts: the hub is the installed command ``edge-monitor slcan-hub``."""

import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from edge_monitor.cli import main  # noqa: E402

if __name__ == "__main__":
    sys.exit(main(["slcan-hub", *sys.argv[1:]]))
