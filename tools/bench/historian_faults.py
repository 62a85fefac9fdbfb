"""Fault runs of the historian (docs/RELIABILITY.md): real processes — `edge-monitor router`, `edge-monitor
historian`, a simulated agent publishing real records through ``SymptomPublisher`` (caches of 256 per key,
as the agent) and writing its JSONL file as the agent does — and one fault in the middle of the stream:

* ``historian-kill``: kill -9 of the historian, restarted 5 s later (it catches up from the caches);
* ``database-kill``: kill -9 of the PostgreSQL server, restarted 5 s later (the historian keeps the records
  in memory and retries);
* ``router-restart``: the router stopped and started again on the same port;
* ``replay``: the agent publishes its first records again (a restarted agent re-sending its file's tail);
* ``disk-full``: SQLite capped at a few MB (``max_page_count``, a full disk without root), the historian
  restarted on the freed disk after the stream.

Afterwards every published symptom must be in the database exactly once; what is missing is reported
with its cycle ranges, then `historian import` of the agent's JSONL fills it (counted apart).

    python tools/bench/historian_faults.py --json            # all five, ~4 minutes
"""

from __future__ import annotations

import argparse
import json
import os
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

TOOLS = Path(__file__).resolve().parent
ROOT = TOOLS.parents[1]
sys.path[:0] = [str(ROOT), str(TOOLS)]

from historian_load import EDGE, template_records  # noqa: E402
from throwaway_postgres import ThrowawayPostgres  # noqa: E402

from edge_monitor.records import to_json, utc_text  # noqa: E402
from edge_monitor.sinks.loopback import free_loopback_port  # noqa: E402

SCENARIOS = ("historian-kill", "database-kill", "router-restart", "replay", "disk-full")
ROBOTS, JOINTS = 3, 6


def agent(args: argparse.Namespace) -> None:
    """The simulated agent: ``--cycles`` cycles per robot at ``--rate`` cycles/s, JSONL written first."""
    from edge_monitor.sinks.zenoh_publisher import SymptomPublisher
    from edge_monitor.sinks.zenoh_session import ZenohOptions, open_session
    templates = json.loads(Path(args.templates).read_text())
    session = open_session(ZenohOptions(mode="client", connect=[args.connect]))
    publishers = {f"r{i}": SymptomPublisher(session, f"r{i}", range(JOINTS)) for i in range(ROBOTS)}
    deadline = time.monotonic() + 30
    while not all(p.has_subscriber() for p in publishers.values()) and time.monotonic() < deadline:
        time.sleep(0.05)
    sent: list[dict[str, Any]] = []
    with open(args.jsonl, "a") as jsonl:
        for cycle in range(args.cycles):
            stamp = utc_text(time.time())
            for robot, publisher in publishers.items():
                for joint in range(JOINTS):
                    record = {**templates[joint % len(templates)], "robot": robot, "joint": joint, "cycle": cycle,
                              "t": cycle * 30.0, "utc": stamp}
                    jsonl.write(to_json(record) + "\n")
                    jsonl.flush()
                    publisher.publish_symptom(record)
                    sent.append(record)
            if args.replay_at == cycle:                     # a restarted agent sends its file's tail again
                for record in sent[: len(sent) // 2]:
                    publishers[record["robot"]].publish_symptom(record)
            time.sleep(1.0 / args.rate)
    time.sleep(float(args.linger))                          # caches stay up: a late historian recovers
    for publisher in publishers.values():
        publisher.close()
    session.close()


def _start_historian(db: str, endpoint: str, env: dict[str, str]) -> subprocess.Popen:
    proc = subprocess.Popen([EDGE, "historian", "--db", db, "--zenoh-mode", "client", "--zenoh-connect", endpoint,
                             "-q"], stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True, env=env)
    proc.stdout.readline()                                                 # type: ignore[union-attr]
    return proc


def _router(port: str) -> subprocess.Popen:
    proc = subprocess.Popen([EDGE, "router", "--port", port], stdout=subprocess.PIPE, text=True)
    proc.stdout.readline()                                                 # type: ignore[union-attr]
    return proc


def _stored(db: str, env: dict[str, str]) -> list[tuple]:
    sql = "SELECT robot, joint, cycle, utc FROM records WHERE kind = 'symptom'"
    if db.startswith("postgresql"):
        import psycopg
        with psycopg.connect(db, password=env["PGPASSWORD"]) as conn:
            return [tuple(r) for r in conn.execute(sql).fetchall()]
    import sqlite3
    with sqlite3.connect(db.split("?")[0].removeprefix("sqlite:///")) as conn:
        return conn.execute(sql).fetchall()


def _ranges(missing: list[tuple]) -> list[str]:
    by_joint: dict[tuple, list[int]] = {}
    for robot, joint, cycle, _utc in missing:
        by_joint.setdefault((robot, joint), []).append(cycle)
    return [f"{r} joint {j}: cycles {min(c)}–{max(c)} ({len(c)})" for (r, j), c in sorted(by_joint.items())]


def run_scenario(name: str, folder: Path, cycles: int, rate: float) -> dict[str, Any]:
    work = folder / name
    work.mkdir()
    pg = ThrowawayPostgres() if name == "database-kill" else None
    env = dict(os.environ)
    if pg is not None:
        pg.start()
        db, env = pg.url, pg.client_env()
    elif name == "disk-full":
        db = f"sqlite:///{work / 'plant.db'}?max_page_count=1200"              # 4.7 MB: full mid-stream
    else:
        db = str(work / "plant.db")
    templates = work / "templates.json"
    templates.write_text(json.dumps(template_records(None, work)))
    port = str(free_loopback_port())
    endpoint = f"tcp/127.0.0.1:{port}"
    router = _router(port)
    historian = _start_historian(db, endpoint, env)
    jsonl = work / "agent.jsonl"
    publisher = subprocess.Popen([sys.executable, __file__, "--agent", "--connect", endpoint, "--templates",
                                  str(templates), "--jsonl", str(jsonl), "--cycles", str(cycles), "--rate", str(rate),
                                  "--replay-at", str(cycles // 2 if name == "replay" else -1), "--linger",
                                  "90" if name == "disk-full" else "20"])
    time.sleep(cycles / rate / 3)                                          # mid-stream
    if name == "historian-kill":
        historian.kill()
        historian.wait()
        time.sleep(5)
        historian = _start_historian(db, endpoint, env)
    elif name == "database-kill" and pg is not None:
        pg.kill()
        time.sleep(5)
        pg.restart()
    elif name == "router-restart":
        router.send_signal(signal.SIGTERM)
        router.wait(30)
        time.sleep(2)
        router = _router(port)
    if name == "disk-full":       # after the stream, while the agent's caches are up: the disk is freed
        time.sleep(cycles / rate * 2 / 3 + 2)
        historian.send_signal(signal.SIGTERM)
        historian.wait(90)
        db = str(work / "plant.db")
        historian = _start_historian(db, endpoint, env)
        time.sleep(15)
    publisher.wait(timeout=cycles / rate * 4 + 180)
    time.sleep(3)
    historian.send_signal(signal.SIGTERM)
    historian.wait(120)
    published = {(r["robot"], r["joint"], r["cycle"], r["utc"]) for r in map(json.loads, jsonl.read_text().splitlines())}
    stored = _stored(db, env)
    missing = sorted(published - set(stored))
    imported: dict[str, Any] = {}
    if missing:
        done = subprocess.run([EDGE, "historian", "import", str(jsonl), "--db", db, "--json"], capture_output=True,
                              text=True, env=env)
        imported = json.loads(done.stdout or "{}")
    after = _stored(db, env)
    router.send_signal(signal.SIGTERM)
    router.wait(30)
    if pg is not None:
        pg.stop()
    return {"scenario": name, "published": len(published), "stored_live": len(stored),
            "duplicates_in_db": len(after) - len(set(after)), "missing_live": len(missing),
            "missing_ranges": _ranges(missing)[:6], "filled_by_import": imported.get("stored", 0) // 2 if imported else 0,
            "missing_after_import": len(published - set(after))}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--scenario", action="append", choices=SCENARIOS, help="(repeatable; default: all)")
    parser.add_argument("--cycles", type=int, default=60, help="cycles per robot (3 robots × 6 joints)")
    parser.add_argument("--rate", type=float, default=2.0, help="cycles per second per robot")
    parser.add_argument("--json", action="store_true")
    for hidden in ("--agent",):
        parser.add_argument(hidden, action="store_true", help=argparse.SUPPRESS)
    for hidden in ("--connect", "--templates", "--jsonl", "--replay-at", "--linger"):
        parser.add_argument(hidden, help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.agent:
        args.replay_at = int(args.replay_at)
        agent(args)
        return
    folder = Path(tempfile.mkdtemp(prefix="historian-faults-"))
    results = [run_scenario(name, folder, args.cycles, args.rate) for name in (args.scenario or SCENARIOS)]
    if args.json:
        print(json.dumps(results, indent=1))
    else:
        for r in results:
            print(f"{r['scenario']:>15}: published {r['published']}, stored live {r['stored_live']}, missing "
                  f"{r['missing_live']} {r['missing_ranges']}, filled by import {r['filled_by_import']}, duplicates "
                  f"{r['duplicates_in_db']}, missing after import {r['missing_after_import']}")
    sys.exit(1 if any(r["duplicates_in_db"] or r["missing_after_import"] for r in results) else 0)


if __name__ == "__main__":
    main()
