#!/usr/bin/env python3
"""The soak's independent Zenoh subscriber: every symptom it receives, as one JSON line.

    python tools/soak/soak_subscriber.py --connect tcp/127.0.0.1:PORT --key 'edge/soak/*/symptom' --out got.jsonl

A Zenoh client of the router (multicast scouting off) with the agent's own advanced subscriber
(history of late publishers, heartbeat recovery). Each received symptom is written as
``{"robot", "joint", "cycle", "partial", "t"}`` and flushed at once — duplicates too, one line each.
Prints ``subscriber ready`` once declared; stops on SIGTERM/SIGINT with a last line ``{"misses": N}``
(samples Zenoh reported as lost and not recovered).
"""

from __future__ import annotations

import argparse
import json
import logging
import signal
import sys
import threading
import time
from pathlib import Path
from typing import Any, Callable, TextIO

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))

from edge_monitor.sinks.zenoh_publisher import ReceivedRecord, SymptomSubscriber  # noqa: E402
from edge_monitor.sinks.zenoh_session import ZenohOptions, open_session  # noqa: E402

#: More fields for a line: (the symptom record, time.monotonic() on its arrival) → fields.
Extra = Callable[[dict[str, Any], float], dict[str, Any]]


class LineWriter:
    """Writes one JSON line per received symptom (called on Zenoh's threads), with the ``extra``
    fields if given."""

    def __init__(self, out: TextIO, extra: Extra | None = None) -> None:
        self.out = out
        self.extra = extra
        self.lock = threading.Lock()

    def __call__(self, received: ReceivedRecord) -> None:
        arrived = time.monotonic()
        if received.kind != "symptom":
            return
        r = received.record
        fields = {"robot": r.get("robot"), "joint": r.get("joint"), "cycle": r.get("cycle"),
                  "partial": bool(r.get("partial")), "t": r.get("t")}
        if self.extra is not None:
            fields.update(self.extra(r, arrived))
        line = json.dumps(fields)
        with self.lock:
            self.out.write(line + "\n")
            self.out.flush()


def serve(connect: str, key: str, out_path: str | Path, extra: Extra | None = None) -> int:
    """Subscribe as a client of the router at ``connect`` and append one line per symptom to
    ``out_path`` until SIGTERM/SIGINT; then the line ``{"misses": N}``."""
    stop = threading.Event()
    for signum in (signal.SIGINT, signal.SIGTERM):
        signal.signal(signum, lambda *_: stop.set())
    session = open_session(ZenohOptions(mode="client", connect=[connect]))
    with open(out_path, "a", encoding="utf-8") as out:
        writer = LineWriter(out, extra)
        subscriber = SymptomSubscriber(session, key, history=True, callback=writer, keep=False)
        print("subscriber ready", flush=True)
        stop.wait()
        subscriber.close()
        with writer.lock:
            out.write(json.dumps({"misses": subscriber.misses}) + "\n")
    session.close()
    return 0


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--connect", required=True, help="router endpoint, e.g. tcp/127.0.0.1:7447")
    ap.add_argument("--key", default="edge/**", help="key expression of the symptoms")
    ap.add_argument("--out", required=True, help="JSON Lines file to append to")
    args = ap.parse_args()
    logging.basicConfig(level=logging.WARNING, format="%(asctime)s %(name)s: %(message)s")
    return serve(args.connect, args.key, args.out)


if __name__ == "__main__":
    sys.exit(main())
