"""Shared pieces of the historian's tests: a throwaway PostgreSQL (tools/bench/throwaway_postgres.py; the
tests on it skip with its reason where it cannot run), a fresh database per test on either engine, and
records shaped as the agent publishes them."""

from __future__ import annotations

import itertools
import sys
from contextlib import ExitStack
from pathlib import Path
from typing import Any, Iterator

import pytest

from edge_monitor.historian.db_url import DbTarget, parse_db
from edge_monitor.records import to_json, utc_text

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tools" / "bench"))

from throwaway_postgres import ThrowawayPostgres  # noqa: E402

START = 1_795_000_000.0            # 2026-11-18: the records' wall time starts here
CYCLE_S = 30.0
ENGINES = ("sqlite", "postgresql")
_names = itertools.count()


@pytest.fixture(scope="session")
def postgres() -> Iterator[ThrowawayPostgres]:
    server = ThrowawayPostgres(fsync=False)    # tests kill processes, not the machine: fsync buys nothing here
    reason = server.unavailable()
    if reason:
        pytest.skip(f"no PostgreSQL here: {reason}")
    with server:
        yield server


def fresh_database(engine: str, tmp_path: Path, request: pytest.FixtureRequest, monkeypatch) -> DbTarget:
    """A new, empty database on ``engine`` (PostgreSQL: a new database on the session's server, its
    password in PGPASSWORD as the historian wants it)."""
    if engine == "sqlite":
        return parse_db(str(tmp_path / "history.db"))
    server: ThrowawayPostgres = request.getfixturevalue("postgres")
    import psycopg
    name = f"t{next(_names)}"
    with psycopg.connect(f"host=127.0.0.1 port={server.port} user=historian dbname=historian "
                         f"password={server.password}", autocommit=True) as conn:
        conn.execute(f"CREATE DATABASE {name}")
    monkeypatch.setenv("PGPASSWORD", server.password)
    return parse_db(f"postgresql://historian@127.0.0.1:{server.port}/{name}")


def symptom(robot: str, joint: int, cycle: int, wear: float | None = 10.0, at: float | None = None,
            prognosis: dict[str, Any] | None = None, alarm: bool = False, **extra: Any) -> dict[str, Any]:
    """A symptom record with the published fields the historian reads (others as the agent has them)."""
    at = START + cycle * CYCLE_S if at is None else at
    record: dict[str, Any] = {
        "schema": 1, "robot": robot, "joint": joint, "cycle": cycle, "t": cycle * CYCLE_S, "utc": utc_text(at),
        "friction": {"speeds": [8.7, 41.7], "torque": [0.08, 0.1], "stderr": [1e-4, 1e-4]},
        "wear": {"estimate": wear, "std": 2.0, "temperature": 40.0, "upper_95": None if wear is None else wear + 4,
                 "identifiable": True},
        "kl": {"raw": 0.1, "weighted": 0.1}, "decisions": {}, "alarm": alarm, "load": {"mean": 0.5, "std": 0.1},
        "skipped": {}, "critical_wear": 35.0}
    if prognosis is not None:
        record["prognosis"] = prognosis
    record.update(extra)
    return record


def alarm(robot: str, joint: int, cycle: int, state: str, fault_cycle: int, at: float | None = None,
          open_: bool | None = None) -> dict[str, Any]:
    at = START + cycle * CYCLE_S if at is None else at
    is_open = state in ("raised", "updated", "chattering") if open_ is None else open_
    return {"schema": 1, "robot": robot, "joint": joint, "cycle": cycle, "utc": utc_text(at), "quantity": "wear",
            "state": state, "statistic": 12.0, "threshold": 5.0, "miss_probability": 0.01, "change_cycle": fault_cycle,
            "fault": f"{robot}/{joint}/{fault_cycle}", "open": is_open,
            "detectors": [{"quantity": "wear", "cycle": fault_cycle}]}


def prognosis(days: float | None) -> dict[str, Any]:
    """The prognosis section another branch adds to every symptom (None days: beyond the horizon)."""
    band = None if days is None else {"median": days, "p10": days * 0.6, "p90": days * 1.5}
    return {"model": "wiener", "state": "forecasting", "critical_wear": 35.0, "wear_rate_per_day": 0.1,
            "cycles": None if days is None else {k: v * 300 for k, v in band.items()},  # type: ignore[union-attr]
            "days": band, "beyond_horizon": days is None, "horizon_days": 365,
            "p_critical": {"7": 0.01, "30": 0.2}}


def write_jsonl(path: Path, symptoms: list[dict], alarms: list[dict] = ()) -> Path:  # type: ignore[assignment]
    lines = [to_json(r) for r in symptoms] + [to_json({"kind": "alarm", **a}) for a in alarms]
    path.write_text("".join(line + "\n" for line in lines))
    return path


__all__ = ["ENGINES", "ExitStack", "START", "alarm", "fresh_database", "postgres", "prognosis", "symptom",
           "write_jsonl"]
