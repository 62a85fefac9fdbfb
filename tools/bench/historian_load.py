"""Plant-scale load on the historian: N simulated agents publishing real records over Zenoh → one
`edge-monitor router` → one `edge-monitor historian` → SQLite or PostgreSQL (docs/BENCHMARKS.md).

Each simulated agent is a real ``SymptomPublisher`` (advanced publishers with caches, liveliness, health)
in one of ``--processes`` publisher processes; every cycle it publishes a symptom and a friction curve per
joint, made from records of a real replay (``--template``, default: a 2-joint recording replayed here),
and a health record every ``--health-every`` seconds. The record's ``utc`` is the moment it is published,
so the historian's ``stored`` column minus it is the end-to-end latency (publish → committed), read
back from the database. Load is stated as plant equivalents: 1 000 six-joint robots at 300 cycles a day
publish 20.8 symptoms, 20.8 friction curves and 100 health records a second (health every 10 s).

    python tools/bench/historian_load.py --robots 1000 --cycles-per-day 3000 --health-every 1 --db sqlite
    python tools/bench/historian_load.py --robots 1000 --cycles-per-day 3000 --health-every 1 --db postgresql

Prints one JSON report: published and stored per kind (lost = published − stored; the database's
identity makes a duplicate impossible, the historian counts redeliveries), sustained records/s, latency
p50/p99/max, CPU seconds and peak RSS of the router and the historian, database bytes per record and per
robot-year.
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

from throwaway_postgres import ThrowawayPostgres  # noqa: E402

from edge_monitor.records import to_json, utc_text  # noqa: E402
from edge_monitor.sinks.loopback import free_loopback_port  # noqa: E402

BIN = Path(sys.executable).parent
EDGE = str(BIN / "edge-monitor")
JOINTS = 6
DAY_S = 86400.0


def template_records(path: str | None, folder: Path) -> list[dict[str, Any]]:
    """Symptom records of a real replay (the last cycle's of each joint: monitoring, full size)."""
    if path is None:
        log, out = folder / "t.blf", folder / "t.jsonl"
        subprocess.run([str(BIN / "sim-controller"), "record", "-o", str(log), "--joints", "2", "--cycles", "6",
                        "--start-time", "1795000000", "-q"], check=True)
        subprocess.run([EDGE, "replay", str(log), "--jsonl", str(out), "-q"], check=True)
        path = str(out)
    records = [json.loads(line) for line in Path(path).read_text().splitlines()]
    return [r for r in records if "kind" not in r][-2:]


def health_record(robot: str, cycles: int, wall_s: float) -> dict[str, Any]:
    """A health record with every field its schema requires (the historian refuses one without them)."""
    return {"schema": 1, "robot": robot, "utc": utc_text(time.time()), "frames_total": 0, "frames_ok": 0,
            "crc_errors": 0, "counter_lost": 0, "cycles": cycles, "symptoms": cycles * JOINTS, "alarms": 0,
            "frames_per_second": 0.0, "wall_s": round(wall_s, 3)}


# -- a publisher process ----------------------------------------------------------------------------


def publish(args: argparse.Namespace) -> None:
    from edge_monitor.sinks.zenoh_publisher import SymptomPublisher
    from edge_monitor.sinks.zenoh_session import ZenohOptions, open_session
    templates = json.loads(Path(args.templates).read_text())
    session = open_session(ZenohOptions(mode="client", connect=[args.connect]))
    robots = args.names.split(",")
    publishers = {r: SymptomPublisher(session, r, range(JOINTS)) for r in robots}
    deadline = time.monotonic() + 60
    while not all(p.has_subscriber() for p in publishers.values()) and time.monotonic() < deadline:
        time.sleep(0.05)
    counts = {"symptom": 0, "friction": 0, "health": 0}
    cycle_period = DAY_S / args.cycles_per_day                 # per robot [s]
    start = time.monotonic()
    next_cycle = {r: start + i * cycle_period / len(robots) for i, r in enumerate(robots)}
    next_health = {r: start + i * args.health_every / len(robots) for i, r in enumerate(robots)}
    cycle_of = dict.fromkeys(robots, 0)
    end = start + args.duration
    while (now := time.monotonic()) < end:
        for robot, publisher in publishers.items():
            if now >= next_cycle[robot]:
                next_cycle[robot] += cycle_period
                stamp = utc_text(time.time())
                for joint in range(JOINTS):
                    record = {**templates[joint % len(templates)], "robot": robot, "joint": joint,
                              "cycle": cycle_of[robot], "t": cycle_of[robot] * 30.0, "utc": stamp}
                    publisher.publish_symptom(record)
                    publisher.publish_friction({"schema": 1, "robot": robot, "joint": joint, "cycle": record["cycle"],
                                                "utc": stamp, **record["friction"]})
                    counts["symptom"] += 1
                    counts["friction"] += 1
                cycle_of[robot] += 1
            if now >= next_health[robot]:
                next_health[robot] += args.health_every
                publisher.publish_health(health_record(robot, cycle_of[robot], now - start))
                counts["health"] += 1
        time.sleep(0.005)
    time.sleep(1.0)
    undelivered = sum(sum(p.undelivered.values()) for p in publishers.values())
    for publisher in publishers.values():
        publisher.close()
    session.close()
    print(to_json({**counts, "undelivered": undelivered}), flush=True)


# -- measuring the router and the historian ---------------------------------------------------------


def cpu_seconds(pid: int) -> float:
    fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


def rss_mib(pid: int) -> float:
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        if line.startswith("VmRSS:"):
            return int(line.split()[1]) / 1024
    return 0.0


def database_rows(db: str, env: dict[str, str], after: float = 0.0) -> tuple[dict[str, int], list[float], int]:
    """(stored per kind, latencies of symptoms published after ``after`` [Unix s], database bytes)."""
    if db.startswith("postgresql"):
        import psycopg
        with psycopg.connect(db, password=env["PGPASSWORD"]) as conn:
            kinds: dict[str, int] = dict(conn.execute("SELECT kind, COUNT(*) FROM records GROUP BY kind").fetchall())
            lat = [r[0] for r in conn.execute("SELECT stored - at FROM records WHERE kind = 'symptom' AND at > %s",
                                                  (after,)).fetchall()]
            size = (conn.execute("SELECT pg_database_size(current_database())").fetchone() or (0,))[0]
        return kinds, lat, int(size)
    import sqlite3
    with sqlite3.connect(db) as conn:
        conn.execute("PRAGMA wal_checkpoint(TRUNCATE)")
        kinds = dict(conn.execute("SELECT kind, COUNT(*) FROM records GROUP BY kind").fetchall())
        lat = [r[0] for r in conn.execute("SELECT stored - at FROM records WHERE kind = 'symptom' AND at > ?",
                                          (after,)).fetchall()]
    return kinds, lat, Path(db).stat().st_size


def percentile(values: list[float], q: float) -> float | None:
    if not values:
        return None
    ordered = sorted(values)
    return ordered[min(len(ordered) - 1, int(q * len(ordered)))]


def run(args: argparse.Namespace) -> dict[str, Any]:
    folder = Path(tempfile.mkdtemp(prefix="historian-load-"))
    pg = ThrowawayPostgres() if args.db == "postgresql" else None
    env = dict(os.environ)
    if pg is not None:
        pg.start()
        db, env = pg.url, pg.client_env()
    else:
        db = str(folder / "plant.db")
    templates = folder / "templates.json"
    templates.write_text(json.dumps(template_records(args.template, folder)))
    endpoint = f"tcp/127.0.0.1:{free_loopback_port()}"
    router = subprocess.Popen([EDGE, "router", "--port", endpoint.rsplit(":", 1)[1]], stdout=subprocess.PIPE, text=True)
    router.stdout.readline()                                               # type: ignore[union-attr]
    historian = subprocess.Popen([EDGE, "historian", "--db", db, "--zenoh-mode", "client", "--zenoh-connect",
                                  endpoint, "--json", *(["--no-history"] if args.no_history else [])], stdout=subprocess.PIPE, text=True, env=env)
    historian.stdout.readline()                                            # type: ignore[union-attr]
    names = [f"cell{i:04d}" for i in range(args.robots)]
    share = [names[i::args.processes] for i in range(args.processes)]
    publishers = [subprocess.Popen([sys.executable, __file__, "--publisher", "--connect", endpoint, "--names",
                                    ",".join(part), "--templates", str(templates), "--duration", str(args.duration),
                                    "--cycles-per-day", str(args.cycles_per_day), "--health-every",
                                    str(args.health_every)], stdout=subprocess.PIPE, text=True) for part in share]
    time.sleep(min(10.0, args.duration / 4))                               # declarations settle
    steady_from = time.time()
    cpu0 = {name: cpu_seconds(p.pid) for name, p in (("router", router), ("historian", historian))}
    t0, peak = time.monotonic(), {"router": 0.0, "historian": 0.0}
    outputs = []
    for p in publishers:
        while p.poll() is None:
            for name, proc in (("router", router), ("historian", historian)):
                peak[name] = max(peak[name], rss_mib(proc.pid))
            time.sleep(0.5)
        outputs.append(json.loads(p.stdout.read().strip().splitlines()[-1]))   # type: ignore[union-attr]
    window = time.monotonic() - t0
    cpu = {name: cpu_seconds(p.pid) - cpu0[name] for name, p in (("router", router), ("historian", historian))}
    published = {k: sum(o[k] for o in outputs) for k in ("symptom", "friction", "health", "undelivered")}
    deadline = time.monotonic() + 120
    while time.monotonic() < deadline:                                     # the historian drains its queue
        kinds, latencies, size = database_rows(db, env)
        if kinds.get("symptom", 0) >= published["symptom"] and kinds.get("friction", 0) >= published["friction"]:
            break
        time.sleep(1.0)
    historian.send_signal(signal.SIGTERM)
    status = json.loads(historian.communicate(timeout=120)[0] or "{}")
    router.send_signal(signal.SIGTERM)
    router.wait(30)
    kinds, latencies, size = database_rows(db, env, steady_from)
    if pg is not None:
        pg.stop()
    rows = sum(kinds.values())
    per_robot_day = JOINTS * 300 * 2 + DAY_S / 600.0                       # symptoms + curves + sampled health
    return {
        "db": args.db, "robots": args.robots, "history": not args.no_history, "processes": args.processes, "duration_s": args.duration,
        "cycles_per_day": args.cycles_per_day, "health_every_s": args.health_every,
        "plant_equivalent": round(args.robots * args.cycles_per_day / 300 / 1000, 2),
        "offered_per_s": {k: round(v / args.duration, 1) for k, v in published.items() if k != "undelivered"},
        "published": published, "stored": kinds,
        "lost": {k: published[k] - kinds.get(k, 0) for k in ("symptom", "friction")},
        "historian_duplicates": status.get("duplicates"), "historian_lost": status.get("lost_queue_full"),
        "received_per_s": round(status.get("received", 0) / max(window, 1e-9), 1),
        "latency_s (after the first 10 s)": {"p50": percentile(latencies, 0.5), "p99": percentile(latencies, 0.99),
                      "max": max(latencies) if latencies else None},
        "cpu_share": {k: round(v / window, 3) for k, v in cpu.items()}, "peak_rss_mib": peak,
        "db_bytes": size, "bytes_per_row": round(size / max(rows, 1), 1),
        "gb_per_robot_year_unthinned": round(size / max(rows, 1) * per_robot_day * 365 / 1e9, 3),
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--robots", type=int, default=100)
    parser.add_argument("--cycles-per-day", type=float, default=3000.0, help="per robot (300: a plant's day)")
    parser.add_argument("--health-every", type=float, default=10.0, help="seconds between a robot's health records")
    parser.add_argument("--duration", type=float, default=60.0, help="seconds of publishing")
    parser.add_argument("--processes", type=int, default=2, help="publisher processes")
    parser.add_argument("--db", choices=("sqlite", "postgresql"), default="sqlite")
    parser.add_argument("--template", default=None, help="a JSONL file of real symptom records")
    parser.add_argument("--no-history", action="store_true", help="the historian does not ask the caches")
    parser.add_argument("--publisher", action="store_true", help=argparse.SUPPRESS)
    parser.add_argument("--connect", help=argparse.SUPPRESS)
    parser.add_argument("--names", help=argparse.SUPPRESS)
    parser.add_argument("--templates", help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.publisher:
        publish(args)
    else:
        print(json.dumps(run(args), indent=1))


if __name__ == "__main__":
    main()
