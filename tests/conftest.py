"""Test-session set-up shared by all tests."""

import os

# Same as the command-line entry points: single-threaded BLAS (see edge_monitor/cli.py).
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

from hypothesis import settings  # noqa: E402

# CI runs are reproducible (same examples every run); local runs explore new examples.
settings.register_profile("ci", derandomize=True, deadline=None)
if os.environ.get("CI"):
    settings.load_profile("ci")
