"""Test-session set-up shared by all tests."""

import os

# Same as the command-line entry points: single-threaded BLAS (see edge_monitor/cli.py).
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
