"""The README's plant set-up, run as written (router, two robots each with a simulated controller and a live
agent, the historian, two `history` questions), once on SQLite and once on a throwaway PostgreSQL: every
record the agents wrote to their JSONL files is in the database exactly once, and the questions answer."""

from __future__ import annotations

import csv
import io
import json
import re
import sqlite3
import sys
from pathlib import Path

import pytest
from historian_support import postgres  # noqa: F401 (a fixture)
from test_readme import README, _run_block

from edge_monitor.sinks.loopback import free_loopback_port

pytestmark = [pytest.mark.slow, pytest.mark.timeout(900)]

PORTS = ("7447", "7501", "7502")


def fleet_block() -> str:
    blocks = re.findall(r"```sh\n(.*?)```", README.read_text(encoding="utf-8"), re.S)
    return next(b for b in blocks if "edge-monitor historian --db" in b)


def run_fleet(tmp_path: Path, db: str, env_prefix: str = "") -> str:
    script = fleet_block().replace(".venv/bin/", str(Path(sys.executable).parent) + "/")
    for port in PORTS:
        script = re.sub(rf"\b{port}\b", str(free_loopback_port()), script)
    script = env_prefix + script.replace("--db plant.db", f"--db {db}")
    code, output = _run_block(script, tmp_path)
    assert code == 0 and "Traceback" not in output, output[-4000:]
    return output


def identities(path: Path) -> set[tuple[str, int, int, str]]:
    lines = [json.loads(line) for line in path.read_text().splitlines()]
    return {(r["robot"], r["joint"], r["cycle"], r["utc"]) for r in lines if "kind" not in r}


def check(output: str, tmp_path: Path, stored: list[tuple]) -> None:
    written = identities(tmp_path / "r1.jsonl") | identities(tmp_path / "r2.jsonl")
    assert len(written) == 8                                  # 2 robots × 2 joints × 2 cycles
    assert sorted(stored) == sorted(written)                  # every record, exactly once
    table = list(csv.DictReader(io.StringIO(output[output.index("rank,robot"):])))[:4]
    assert sorted((row["robot"], row["joint"]) for row in table) == [("r1", "0"), ("r1", "1"), ("r2", "0"),
                                                                     ("r2", "1")]
    r2 = [json.loads(line) for line in output.splitlines() if line.startswith('{"robot":"r2"')]
    assert sorted((r["joint"], r["cycle"]) for r in r2) == [(0, 0), (0, 1), (1, 0), (1, 1)]


def test_the_readme_plant_on_sqlite(tmp_path):
    output = run_fleet(tmp_path, "plant.db")
    with sqlite3.connect(tmp_path / "plant.db") as db:
        stored = db.execute("SELECT robot, joint, cycle, utc FROM records WHERE kind = 'symptom'").fetchall()
    check(output, tmp_path, stored)


def test_the_readme_plant_on_postgresql(tmp_path, postgres):  # noqa: F811
    import psycopg
    output = run_fleet(tmp_path, postgres.url, env_prefix=f"export PGPASSWORD={postgres.password}\n")
    with psycopg.connect(f"host=127.0.0.1 port={postgres.port} user=historian dbname=historian "
                         f"password={postgres.password}") as db:
        stored = db.execute("SELECT robot, joint, cycle, utc FROM records WHERE kind = 'symptom'").fetchall()
    check(output, tmp_path, stored)
