"""A PostgreSQL server that takes no writes for a while — a hot standby in recovery during a failover,
simulated on a throwaway server with ``default_transaction_read_only`` (ALTER SYSTEM + reload) — is an
outage, not a damaged database: the writer keeps running, holds the records, says in one line that the
server is read-only and what to do if that lasts, and stores every record once the server takes writes
again. (A read-only SQLite file stays unusable: tests/test_historian_damage.py.)"""

from __future__ import annotations

import logging
from typing import Iterator

import pytest
from historian_support import fresh_database, postgres  # noqa: F401  (the fixture)
from test_historian_damage import rows

from edge_monitor.historian import writer
from edge_monitor.historian.database import DatabaseStandby, DatabaseUnavailable, DatabaseUnusable, connect
from edge_monitor.historian.writer import Writer

from waiting import wait_until

WAIT_S = 60.0        # an upper bound on a loaded machine, never a speed assertion


@pytest.fixture
def read_only_switch(postgres) -> Iterator:  # noqa: F811
    """``switch(True/False)``: the whole server read-only (as a hot standby is) or writable again; reset
    at the end, whatever happened (the server is shared by the session's tests)."""
    import psycopg
    admin = psycopg.connect(f"host=127.0.0.1 port={postgres.port} user=historian dbname=postgres "
                            f"password={postgres.password} options='-c default_transaction_read_only=off'",
                            autocommit=True)

    def switch(read_only: bool) -> None:
        admin.execute("ALTER SYSTEM SET default_transaction_read_only = on" if read_only
                      else "ALTER SYSTEM RESET default_transaction_read_only")
        admin.execute("SELECT pg_reload_conf()")

    try:
        yield switch
    finally:
        switch(False)
        admin.close()


def test_a_read_only_standby_is_an_outage_and_the_held_records_are_stored_when_it_is_writable(
        tmp_path, request, monkeypatch, read_only_switch, caplog):
    monkeypatch.setattr(writer, "RETRY_S", (0.05,))
    target = fresh_database("postgresql", tmp_path, request, monkeypatch)
    w = Writer(target, batch_size=10, batch_s=0.01).start()
    offered = rows("r1", range(1, 3))
    try:
        for row in offered:
            w.offer(row)
        assert wait_until(lambda: w.stats().get("stored", 0) == len(offered), WAIT_S)
        with caplog.at_level(logging.ERROR, logger="edge_monitor.historian.writer"):
            read_only_switch(True)
            for cycle in range(3, 1000):             # until the writer's session has seen the change
                batch = rows("r1", range(cycle, cycle + 1))
                offered += batch
                for row in batch:
                    w.offer(row)
                assert wait_until(lambda: w.down_since is not None or w.stats().get("stored", 0) == len(offered),
                                  WAIT_S)
                if w.down_since is not None:
                    break
            assert w.down_since is not None
            held = rows("r2", range(1, 4))            # what arrives while the server is a standby
            offered += held
            for row in held:
                w.offer(row)
            assert wait_until(lambda: "CREATE TABLE" in (w.last_error or ""), WAIT_S)     # reconnections too
            stats = w.stats()
            assert w.unusable is None and w.running and stats["database_unusable"] is None
            assert stats["lost"] == 0 and stats["outages"] == 1 and stats.get("stored", 0) < len(offered)
            assert "default_transaction_read_only" in stats["last_database_error"]
        [line] = [r.getMessage() for r in caplog.records if "database unavailable" in r.getMessage()]
        assert "read-only transaction" in line and "hot standby" in line and "point --db at the primary" in line
        assert "Traceback" not in caplog.text and "unusable" not in caplog.text
        read_only_switch(False)
        assert wait_until(lambda: w.stats().get("stored", 0) == len(offered), WAIT_S), w.stats()
        stats = w.stats()
        assert stats["lost"] == 0 and stats["database_down_s"] is None and stats["queue_depth"] == 0
    finally:
        w.stop()
    conn = connect(target)
    try:
        assert conn.rows("SELECT COUNT(*) FROM records")[0][0] == len(offered)
    finally:
        conn.close()


def test_a_standby_is_an_outage_not_an_unusable_database():
    assert issubclass(DatabaseStandby, DatabaseUnavailable) and not issubclass(DatabaseStandby, DatabaseUnusable)
