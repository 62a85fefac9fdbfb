"""edge-monitor slcan-hub: a loopback TCP hub that relays slcan bytes between its clients.

Every byte one client sends goes to all the others, so slcan:socket://127.0.0.1:PORT is a shared
CAN "bus" between processes on a machine without SocketCAN: e.g. the simulator, the agent and
cantools monitor. It listens on 127.0.0.1 only, prints "listening 127.0.0.1:PORT" once ready and
runs until Ctrl-C or SIGTERM. It relays whole slcan lines only. A client that stops reading gets at
most --max-buffer bytes queued; the frames beyond that are dropped for it and counted, as are frames still
queued when a client leaves and malformed input (a warning when a client's drops start; the totals in
one log line at the end).
"""

from __future__ import annotations

import argparse
import sys
import threading

from edge_monitor.sinks.loopback import MAX_PORT, is_port
from protocol.console import EXIT_CODES_HELP, EXIT_FAILURE, UsageError, stop_on_signals
from protocol.slcan_fast import MAX_LINE_LENGTH
from protocol.slcan_hub import SlcanHub


def add_parser(subparsers: argparse._SubParsersAction) -> argparse.ArgumentParser:
    parser = subparsers.add_parser("slcan-hub", help="relay slcan bytes between processes over loopback TCP",
                                   description=__doc__,
                                   epilog=f"{EXIT_CODES_HELP}. Ctrl-C or SIGTERM is the normal end: exit code 0")
    parser.add_argument("--port", type=int, default=0, help="TCP port on 127.0.0.1 (default 0: a free one)")
    parser.add_argument("--max-buffer", type=int, default=1 << 20, metavar="BYTES",
                        help="bytes queued for a client that does not read (default 1 MiB)")
    parser.set_defaults(func=run)
    return parser


def run(args: argparse.Namespace) -> int:
    if not is_port(args.port):
        raise UsageError(f"--port {args.port}: must be 0 … {MAX_PORT}")
    if args.max_buffer < MAX_LINE_LENGTH:
        raise UsageError(f"--max-buffer {args.max_buffer}: must be ≥ {MAX_LINE_LENGTH} (the longest slcan line)")
    try:
        hub = SlcanHub(args.port, args.max_buffer)
    except OSError as exc:
        print(f"edge-monitor slcan-hub: cannot listen on 127.0.0.1:{args.port}: {exc.strerror}", file=sys.stderr)
        return EXIT_FAILURE
    stop = stop_on_signals()
    server = threading.Thread(target=hub.serve_forever, name="slcan-hub", daemon=True)
    server.start()
    print(f"listening 127.0.0.1:{hub.port}", flush=True)
    try:
        while not stop.wait(0.5):
            pass
    finally:
        hub.stop()
        server.join(timeout=5)
        hub.close()                     # logs the totals: a warning if anything was dropped
    return 0
