#!/usr/bin/env python3
"""Run a Zenoh router on loopback for a fleet of agents (there is no zenohd package here).

    python tools/zenoh_router.py [--port 7447] [--host 127.0.0.1]

Agents and viewers then use ``--zenoh-mode client --zenoh-connect tcp/127.0.0.1:7447``.
Multicast scouting is off. Prints ``zenoh router listening on tcp/HOST:PORT`` once ready and exits
cleanly (exit code 0) on SIGINT or SIGTERM.
"""

from __future__ import annotations

import argparse
import logging
import signal
import sys
import threading
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from edge_monitor.sinks.zenoh_session import DEFAULT_ROUTER_PORT, ZenohOptions, ZenohSetupError, open_session  # noqa: E402


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--port", type=int, default=DEFAULT_ROUTER_PORT, help="TCP port (default 7447)")
    parser.add_argument("--host", default="127.0.0.1",
                        help="address to bind (default 127.0.0.1; anything else exposes the router)")
    parser.add_argument("--config", default=None, metavar="FILE.json5",
                        help="Zenoh JSON5 config (TLS, access control); --host/--port still apply")
    args = parser.parse_args(argv)
    logging.basicConfig(level=logging.WARNING, format="%(levelname)s %(name)s: %(message)s")
    endpoint = f"tcp/{args.host}:{args.port}"
    stop = threading.Event()
    for signum in (signal.SIGINT, signal.SIGTERM):
        signal.signal(signum, lambda *_: stop.set())
    try:
        session = open_session(ZenohOptions(mode="router", listen=[endpoint], config_file=args.config))
    except ZenohSetupError as exc:
        print(f"zenoh_router: {exc}", file=sys.stderr)
        return 1
    print(f"zenoh router listening on {endpoint}", flush=True)
    try:
        while not stop.wait(0.2):
            pass
    finally:
        session.close()
    print("zenoh router stopped", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
