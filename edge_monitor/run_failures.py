"""What a run of the agent could not do, as messages and exit codes (the README's rule: 1 when valid options
met a runtime failure, 2 for bad options): an output that could not be opened (:func:`setup_failure`), and
what the agent could not write (:func:`output_failures`). Shared by the commands and by the monitoring
process of ``replay --jobs 2`` (:mod:`edge_monitor.monitor_process`); light to import (``listen`` starts fast).
"""

from __future__ import annotations

import sys
from typing import TYPE_CHECKING

from protocol.console import EXIT_FAILURE, EXIT_USAGE

if TYPE_CHECKING:
    from edge_monitor.pipeline.agent import Agent
    from edge_monitor.pipeline.state_store import StateStore


def output_failures(agent: Agent, store: StateStore | None) -> list[str]:
    """What the agent could not write (each makes ``run``/``replay`` exit with code 1)."""
    problems = []
    if agent.sink_errors():
        problems.append(f"{agent.sink_errors()} record(s) could not be written to an output (sink_errors; "
                        "e.g. a full disk under the JSONL file)")
    if store is not None and store.last_save_error:
        problems.append(f"the last state save failed ({store.last_save_error}); the previous state file is kept")
    return problems


def setup_failure(command: str, exc: Exception) -> int:
    """Report an output that could not be opened; the exit code by the README's rule: 1 when valid
    options met a runtime failure (unreachable router, occupied port, unwritable recording, a JSONL
    file that cannot be opened: an ``OSError``), else 2."""
    from edge_monitor.sinks.rerun_view import RerunUnavailable
    from edge_monitor.sinks.zenoh_session import ZenohUnavailable
    print(f"edge-monitor {command}: {exc}", file=sys.stderr)
    return EXIT_FAILURE if isinstance(exc, (OSError, ZenohUnavailable, RerunUnavailable)) else EXIT_USAGE
