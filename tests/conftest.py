"""Test-session set-up shared by all tests."""

import os

# Same as the command-line entry points: single-threaded BLAS (see edge_monitor/cli.py).
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

from hypothesis import settings  # noqa: E402

# CI runs are reproducible (same examples every run); local runs explore new examples.
settings.register_profile("ci", derandomize=True, deadline=None)
# CI's second pass over the property-based tests only (HYPOTHESIS_ONLY=1, .ci/run): random examples
# from the seed given with --hypothesis-seed (the ISO week there: other examples every week, the same
# ones within a week, so a failure can be reproduced).
settings.register_profile("explore", derandomize=False, deadline=None)
if os.environ.get("HYPOTHESIS_ONLY"):
    settings.load_profile("explore")
elif os.environ.get("CI"):
    settings.load_profile("ci")


def pytest_collection_modifyitems(config, items):
    """With HYPOTHESIS_ONLY=1, run only the tests that hypothesis drives."""
    if not os.environ.get("HYPOTHESIS_ONLY"):
        return
    keep = [item for item in items if getattr(getattr(item, "obj", None), "is_hypothesis_test", False)]
    config.hook.pytest_deselected(items=[item for item in items if item not in keep])
    items[:] = keep
