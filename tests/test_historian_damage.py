"""A damaged or read-only history database is no passing outage: refused at start when opening shows it,
and when a write finds it, the writer says "damaged"/"read-only" with the fix, retries nothing and counts
every record it did not store as lost (the status' ``lost``, the summary line). A locked file stays an
outage: retried, and everything is stored once the other program lets go."""

from __future__ import annotations

import random
import sqlite3
from contextlib import contextmanager
from pathlib import Path
from typing import Iterator

import pytest
from historian_support import START, symptom

import edge_monitor.cli
from edge_monitor.commands.historian import lost_reasons
from edge_monitor.historian import database, writer
from edge_monitor.historian.database import DatabaseDamaged, DatabaseReadOnly, connect
from edge_monitor.historian.db_url import parse_db
from edge_monitor.historian.identity import Row, row_of
from edge_monitor.historian.writer import Writer
from edge_monitor.historian.writes import insert_rows

from waiting import wait_until

WAIT_S = 30.0        # an upper bound on a loaded machine, never a speed assertion


def rows(robot: str, cycles: range) -> list[Row]:
    out = [row_of("symptom", robot, joint, symptom(robot, joint, cycle), START) for cycle in cycles
           for joint in range(6)]
    assert all(isinstance(row, Row) for row in out)
    return out  # type: ignore[return-value]


def history_file(path: Path, cycles: int = 200) -> Path:
    """A history database holding ``cycles`` cycles of six joints, checkpointed into the one file."""
    conn = connect(parse_db(str(path)))
    insert_rows(conn, rows("r1", range(1, cycles + 1)))
    conn.close()
    with sqlite3.connect(path) as raw:
        raw.execute("PRAGMA wal_checkpoint(TRUNCATE)")
    return path


def damage_every_third_page(path: Path) -> None:
    """Random bytes over every third page from the third (the header page and the schema stay readable)."""
    with sqlite3.connect(path) as raw:
        page_size = raw.execute("PRAGMA page_size").fetchone()[0]
    data = bytearray(path.read_bytes())
    rng = random.Random(15)
    for page in range(2, len(data) // page_size, 3):
        data[page * page_size:(page + 1) * page_size] = rng.randbytes(page_size)
    path.write_bytes(bytes(data))


def stop_and_stats(w: Writer) -> dict:
    w.stop()
    return w.stats()


@pytest.mark.parametrize("damage", ["garbage", "half"])
def test_a_file_damaged_where_opening_reads_is_refused_with_what_to_do(tmp_path, capsys, damage):
    path = history_file(tmp_path / "plant.db", cycles=50)
    if damage == "garbage":
        path.write_bytes(random.Random(1).randbytes(100_000))
    else:
        path.write_bytes(path.read_bytes()[:4096 + 100])       # cut inside the schema's pages
    with pytest.raises(DatabaseDamaged, match=r"is damaged .*\.recover"):
        Writer(parse_db(str(path))).start()
    assert edge_monitor.cli.main(["historian", "gaps", "--db", str(path)]) == 1
    err = capsys.readouterr().err
    assert str(path) in err and "damaged" in err and ".recover" in err and "permissions" not in err
    assert len(err.strip().splitlines()) == 1 and "Traceback" not in err


def test_damage_found_by_a_write_is_not_retried_and_every_record_not_stored_is_lost(tmp_path, monkeypatch):
    monkeypatch.setattr(writer, "RETRY_S", (0.01,))
    path = history_file(tmp_path / "plant.db")
    damage_every_third_page(path)
    w = Writer(parse_db(str(path)), batch_size=10, batch_s=0.01).start()   # opening reads only intact pages
    offered = rows("r2", range(1, 21))
    for row in offered:
        assert w.offer(row)
    assert wait_until(lambda: w.unusable is not None and w.depth() == 0, WAIT_S)
    stats = stop_and_stats(w)
    assert stats.get("stored", 0) == 0 and stats["lost"] == stats["lost_database"] == len(offered)
    assert stats["outages"] == 0 and stats["database_down_s"] is None          # never taken for an outage
    assert "damaged" in stats["database_unusable"] and ".recover" in stats["database_unusable"]
    assert sum(r["lost"] for r in stats["lost_ranges"]) == len(offered)
    assert {(r["robot"], r["first_cycle"], r["last_cycle"]) for r in stats["lost_ranges"]} == {("r2", 1, 20)}
    assert lost_reasons(stats) == f" (database unusable {len(offered)})"


def test_a_read_only_database_is_refused_at_start(tmp_path, monkeypatch):
    path = history_file(tmp_path / "plant.db", cycles=5)
    opened = database._open_sqlite

    def read_only(target):       # what a mode-444 file gives a user other than root: reads, no writes
        raw = opened(target)
        raw.execute("PRAGMA query_only = 1")
        return raw

    monkeypatch.setattr(database, "_open_sqlite", read_only)
    with pytest.raises(DatabaseReadOnly, match=r"read-only for this user .*owner and mode"):
        Writer(parse_db(str(path))).start()


def test_a_database_turning_read_only_while_running_counts_the_records_lost(tmp_path, monkeypatch):
    monkeypatch.setattr(writer, "RETRY_S", (0.01,))
    path = history_file(tmp_path / "plant.db", cycles=5)
    w = Writer(parse_db(str(path)), batch_size=10, batch_s=0.01).start()
    assert w._conn is not None
    w._conn.raw.execute("PRAGMA query_only = 1")
    offered = rows("r2", range(1, 6))
    for row in offered:
        w.offer(row)
    assert wait_until(lambda: w.unusable is not None and w.depth() == 0, WAIT_S)
    stats = stop_and_stats(w)
    assert "read-only" in stats["database_unusable"] and stats["outages"] == 0
    assert stats["lost"] == stats["lost_database"] == len(offered) and stats.get("stored", 0) == 0


@contextmanager
def locked_writer(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> Iterator[tuple[Writer, list[Row]]]:
    """A writer offered 60 rows while another program holds the file's write lock (released on leaving), once the
    writer has seen the outage; retries every 10 ms."""
    monkeypatch.setattr(writer, "RETRY_S", (0.01,))
    monkeypatch.setattr(database, "BUSY_TIMEOUT_MS", 20)
    path = history_file(tmp_path / "plant.db", cycles=5)
    w = Writer(parse_db(str(path)), batch_size=10, batch_s=0.01).start()
    other = sqlite3.connect(path, isolation_level=None)
    other.execute("BEGIN IMMEDIATE")                       # another program holds the write lock
    try:
        offered = rows("r2", range(1, 11))
        for row in offered:
            w.offer(row)
        assert wait_until(lambda: w.down_since is not None, WAIT_S)
        yield w, offered
    finally:
        other.execute("ROLLBACK")
        other.close()


def test_a_locked_file_is_an_outage_retried_until_it_is_released(tmp_path, monkeypatch):
    with locked_writer(tmp_path, monkeypatch) as (w, offered):
        assert "locked" in (w.last_error or "") and w.unusable is None
    assert wait_until(lambda: w.stats().get("stored", 0) == len(offered), WAIT_S)
    stats = stop_and_stats(w)
    assert stats["lost"] == 0 and stats["outages"] == 1 and stats["database_unusable"] is None
    assert stats["database_down_s"] is None and lost_reasons(stats) == ""


def test_records_still_waiting_when_a_stop_gives_up_are_counted_lost(tmp_path, monkeypatch):
    with locked_writer(tmp_path, monkeypatch) as (w, offered):
        w.stop(timeout=0)                                  # the database stays locked past the stop
        stats = w.stats()
    assert wait_until(lambda: not w.running, WAIT_S)       # the abandoned thread ends by itself
    assert stats["lost"] == stats["lost_at_stop"] == len(offered) and stats["queue_depth"] == 0
    assert lost_reasons(stats) == f" (not stored at the stop {len(offered)})"
