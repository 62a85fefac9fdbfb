"""Test-session set-up shared by all tests."""

import logging
import os

import pytest

# Same as the command-line entry points: single-threaded BLAS (see edge_monitor/cli.py).
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

from hypothesis import settings  # noqa: E402

# CI runs are reproducible (same examples every run); local runs explore new examples.
settings.register_profile("ci", derandomize=True, deadline=None)
# CI's second pass over the property-based tests only (HYPOTHESIS_ONLY=1, .ci/run): random examples
# from the seed given with --hypothesis-seed (the ISO week there: other examples every week, the same
# ones within a week, so a failure can be reproduced).
settings.register_profile("explore", derandomize=False, deadline=None)
# Local runs: new examples each run, and no per-example deadline either (no test depends on the machine's speed;
# a busy CPU made Hypothesis's default 200 ms deadline fail a test here).
settings.register_profile("local", deadline=None)
if os.environ.get("HYPOTHESIS_ONLY"):
    settings.load_profile("explore")
elif os.environ.get("CI"):
    settings.load_profile("ci")
else:
    settings.load_profile("local")


def pytest_collection_modifyitems(config, items):
    """With HYPOTHESIS_ONLY=1, run only the tests that hypothesis drives."""
    if not os.environ.get("HYPOTHESIS_ONLY"):
        return
    keep = [item for item in items if getattr(getattr(item, "obj", None), "is_hypothesis_test", False)]
    config.hook.pytest_deselected(items=[item for item in items if item not in keep])
    items[:] = keep


@pytest.fixture(autouse=True)
def _logging_as_the_session_had_it():
    """A CLI entry point or a study tool run in-process sets logger levels for good (``-q``: the root at
    ERROR; a study: ``edge_monitor`` at ERROR for its thousands of expected alarms). Each test starts from
    the levels the session had, so a later test still sees the warnings it checks for."""
    manager = logging.Logger.manager
    levels = {name: lg.level for name, lg in manager.loggerDict.items() if isinstance(lg, logging.Logger)}
    root, disabled = logging.getLogger().level, manager.disable
    yield
    for name, lg in list(manager.loggerDict.items()):
        if isinstance(lg, logging.Logger) and lg.level != levels.get(name, logging.NOTSET):
            lg.setLevel(levels.get(name, logging.NOTSET))
    logging.getLogger().setLevel(root)
    logging.disable(disabled)
