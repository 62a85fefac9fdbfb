#!/usr/bin/env python3
"""Thin wrapper kept for old scripts: the router is the installed command ``edge-monitor router``."""

import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from edge_monitor.cli import main  # noqa: E402

if __name__ == "__main__":
    sys.exit(main(["router", *sys.argv[1:]]))
