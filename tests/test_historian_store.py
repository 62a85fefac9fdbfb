"""The historian's database, on SQLite and on a throwaway PostgreSQL, through the same code: each record
stored exactly once whatever brings it (live, again, from a JSONL file, two writers at once), the fleet
answers (latest wear and band, ranking by wear and by the prognosis forecast, open alarms, last
maintenance), retention, gaps, migrations and bounded answers."""

from __future__ import annotations

import dataclasses
import threading

import pytest
from historian_support import (  # noqa: F401 (postgres is a fixture)
    CYCLE_S,
    ENGINES,
    START,
    alarm,
    fresh_database,
    postgres,
    prognosis,
    symptom,
    write_jsonl,
)

from edge_monitor.historian.database import connect, schema_version
from edge_monitor.historian.identity import Rejection, friction_of, row_of
from edge_monitor.historian.jsonl_import import import_files
from edge_monitor.historian.migrations import LATEST_VERSION, MIGRATIONS, SchemaTooNew
from edge_monitor.historian.queries import answer
from edge_monitor.historian.query_spec import HistoryQuery
from edge_monitor.historian.retention import Retention, thin
from edge_monitor.historian.times import DAY_S
from edge_monitor.historian.writer import Writer
from edge_monitor.historian.writes import insert_rows

from waiting import wait_until


@pytest.fixture(params=ENGINES)
def target(request, tmp_path, monkeypatch):
    return fresh_database(request.param, tmp_path, request, monkeypatch)


@pytest.fixture
def conn(target):
    connection = connect(target)
    yield connection
    connection.close()


def rows(kind, records, received=START, joint=None):
    made = [row_of(kind, r["robot"], r.get("joint", joint), r, received) for r in records]
    assert not any(isinstance(m, Rejection) for m in made), made
    return made


def symptoms_with_friction(records, received=START):
    out = []
    for row in rows("symptom", records, received):
        out += [row, friction_of(row)]
    return out


def count(conn, kind=None):
    where, params = ("WHERE kind = ?", (kind,)) if kind else ("", ())
    return conn.rows(f"SELECT COUNT(*) FROM records {where}", params)[0][0]


def test_a_record_is_stored_once_however_often_and_however_it_comes(conn, tmp_path):
    records = [symptom("r1", j, c) for c in range(5) for j in range(2)]
    first = insert_rows(conn, symptoms_with_friction(records))
    assert first.stored == 20 and first.duplicates == 0                  # 10 symptoms + their friction curves
    again = insert_rows(conn, symptoms_with_friction(records))            # a redelivery
    assert again.stored == 0 and again.duplicates == 10 and again.friction_present == 10
    live_friction = [{"schema": 1, "robot": "r1", "joint": r["joint"], "cycle": r["cycle"], "utc": r["utc"],
                      **r["friction"]} for r in records]
    assert insert_rows(conn, rows("friction", live_friction)).stored == 0   # the sample Zenoh also brings
    report = import_files(conn, [str(write_jsonl(tmp_path / "r1.jsonl", records))])    # the agent's file
    assert report.stored == 0 and report.duplicates == 10 and not report.bad_lines
    assert count(conn, "symptom") == 10 and count(conn, "friction") == 10


def test_a_controller_restart_makes_new_records_and_a_republished_cycle_does_not(conn):
    before = [symptom("r1", 0, c) for c in range(3)]
    restarted = [symptom("r1", 0, c, at=START + 3600 + c * CYCLE_S) for c in range(3)]   # cycles 0, 1, 2 again
    insert_rows(conn, rows("symptom", before))
    assert insert_rows(conn, rows("symptom", restarted + before[-1:])).stored == 3
    no_wall_time = [symptom("r2", 0, c, utc=None) for c in range(3)]     # a log with relative time: t tells
    insert_rows(conn, rows("symptom", no_wall_time))
    assert insert_rows(conn, rows("symptom", no_wall_time, received=START + 99)).stored == 0
    assert count(conn, "symptom") == 9


def test_alarm_events_keep_their_own_identity(conn):
    events = [alarm("r1", 0, 90, "raised", 90), alarm("r1", 0, 92, "updated", 90), alarm("r1", 0, 95, "cleared", 90)]
    assert insert_rows(conn, rows("alarm", events)).stored == 3
    assert insert_rows(conn, rows("alarm", events)).duplicates == 3
    second_fault = [alarm("r1", 0, 130, "raised", 130)]
    assert insert_rows(conn, rows("alarm", second_fault)).stored == 1


def test_two_writers_on_one_database_store_each_record_once(target):
    records = [symptom("r1", j, c) for c in range(150) for j in range(6)]
    made = symptoms_with_friction(records)
    writers = [Writer(target, batch_size=50, batch_s=0.01).start() for _ in range(2)]
    # both historians get every record, in a different order, at once
    feeders = [threading.Thread(target=lambda w=w, part=part: [w.offer(r) for r in part])
               for w, part in zip(writers, (made, made[::-1]))]
    for feeder in feeders:
        feeder.start()
    for feeder in feeders:
        feeder.join(60)
    assert wait_until(lambda: sum(w.counts["stored"] + w.counts["duplicates"] + w.counts["friction_present"]
                                  for w in writers) == 2 * len(made), 120)
    for w in writers:
        w.stop()
    assert sum(w.counts["stored"] for w in writers) == len(made) and not any(w.lost.total for w in writers)
    conn = connect(target)
    try:
        assert count(conn) == len(made)
        latest = conn.rows("SELECT robot, joint, cycle FROM joints ORDER BY joint")
        assert latest == [("r1", j, 149) for j in range(6)]          # the newest, whichever writer stored it
    finally:
        conn.close()


def test_the_fleet_is_ranked_by_wear_and_by_the_forecast_with_none_last(conn):
    plain = [symptom("r1", 0, 5, wear=30.0), symptom("r2", 1, 5, wear=12.0)]          # before prognosis existed
    forecast = [symptom("r3", 0, 5, wear=20.0, prognosis=prognosis(40.0)),
                symptom("r4", 2, 5, wear=25.0, prognosis=prognosis(9.5)),
                symptom("r5", 0, 5, wear=5.0, prognosis=prognosis(None))]               # beyond the horizon
    insert_rows(conn, rows("symptom", plain + forecast))
    insert_rows(conn, rows("symptom", [symptom("r1", 0, 4, wear=99.0)]))              # older: not the latest
    by_wear = answer(conn, HistoryQuery(what="fleet", rank="wear"), now=START + 600)
    assert [(j["robot"], j["wear"]["estimate"]) for j in by_wear["joints"]] == [
        ("r1", 30.0), ("r4", 25.0), ("r3", 20.0), ("r2", 12.0), ("r5", 5.0)]
    assert by_wear["joints"][0]["wear"]["band"] == [26.0, 34.0]                       # ϖ̂ ± 2σ
    by_forecast = answer(conn, HistoryQuery(what="fleet", rank="forecast"), now=START + 600)
    assert [j["robot"] for j in by_forecast["joints"]] == ["r4", "r3", "r1", "r2", "r5"]
    assert by_forecast["joints"][0]["forecast_days"] == 9.5 and by_forecast["joints"][0]["prognosis"]["p_critical"]


def test_open_alarms_last_maintenance_and_stale_agents(conn):
    raised = [alarm("r1", 0, 90, "raised", 90), alarm("r2", 3, 50, "raised", 50)]
    insert_rows(conn, rows("alarm", raised))
    opened = answer(conn, HistoryQuery(what="alarms"))
    assert [a["fault"] for a in opened["records"]] == ["r1/0/90", "r2/3/50"]
    insert_rows(conn, rows("alarm", [alarm("r1", 0, 95, "cleared", 90)]))
    insert_rows(conn, rows("alarm", [alarm("r1", 0, 91, "updated", 90)]))             # late: older than cleared
    assert [a["fault"] for a in answer(conn, HistoryQuery(what="alarms"))["records"]] == ["r2/3/50"]
    live = rows("symptom", [symptom("r1", 0, 96), symptom("r2", 3, 51)], received=START + 100)
    insert_rows(conn, live)
    fleet = answer(conn, HistoryQuery(what="fleet", rank="robot", stale_s=3600), now=START + 100 + 7200)
    r1 = fleet["joints"][0]
    assert r1["last_maintenance"]["source"] == "cleared" and r1["last_maintenance"]["cycle"] == 95
    assert fleet["joints"][1]["open_faults"][0]["fault"] == "r2/3/50"
    assert fleet["stale_agents"] == ["r1", "r2"]                   # silent for 2 h with a stale limit of 1 h


def test_retention_thins_old_days_keeps_alarms_and_refuses_thinned_days(conn, tmp_path):
    day0 = [symptom("r1", 0, c, wear=float(c), at=START + c * 600) for c in range(20)]
    insert_rows(conn, symptoms_with_friction(day0))
    insert_rows(conn, rows("alarm", [alarm("r1", 0, 10, "raised", 10, at=START + 6000)]))
    now = START + 400 * DAY_S
    done = thin(conn, Retention(keep_days=180), now=now)
    assert done.summaries == 1 and count(conn, "symptom") == 1 and count(conn, "friction") == 1
    assert count(conn, "alarm") == 1                                   # kept for ever
    daily = answer(conn, HistoryQuery(what="daily", robot="r1"))["records"]
    assert daily[0]["records"] == 20 and daily[0]["wear"] == {"min": 0.0, "max": 19.0, "mean": 9.5}
    assert thin(conn, Retention(keep_days=180), now=now).days == 0     # each day once
    late = import_files(conn, [str(write_jsonl(tmp_path / "old.jsonl", day0))])
    assert late.expired == 40 and late.stored == 0 and count(conn, "symptom") == 1


def test_gaps_are_found_and_an_import_fills_them(conn, tmp_path):
    records = [symptom("r1", 0, c) for c in range(30)]
    insert_rows(conn, rows("symptom", records[:10] + records[20:]))
    gaps = answer(conn, HistoryQuery(what="gaps"))
    assert gaps["gaps"][0] | {"after_utc": None, "before_utc": None} == {
        "robot": "r1", "joint": 0, "first": 10, "last": 19, "missing": 10, "after_utc": None, "before_utc": None}
    report = import_files(conn, [str(write_jsonl(tmp_path / "r1.jsonl", records))])
    assert report.stored == 40 and report.duplicates == 20     # 10 symptoms and all 30 curves were missing
    assert answer(conn, HistoryQuery(what="gaps"))["gaps"] == []


def test_answers_are_bounded_and_page_on(conn):
    insert_rows(conn, rows("symptom", [symptom("r1", j, c) for c in range(400) for j in range(6)]))
    seen, cursor = [], None
    while True:
        page = answer(conn, HistoryQuery(robot="r1", kinds=("symptom",), since=0.0, until=2.5e11, limit=1000,
                                         cursor=cursor))
        seen += [(r["cycle"], r["joint"]) for r in page["records"]]
        if not page["truncated"]:
            break
        from edge_monitor.historian.query_spec import Cursor
        cursor = Cursor.parse(page["next"])
    assert len(seen) == 2400 and len(set(seen)) == 2400 and seen == sorted(seen)
    unknown = answer(conn, HistoryQuery(robot="nosuch"))
    assert unknown["records"] == [] and unknown["robot_known"] is False and "r1" in unknown["message"]


def test_an_old_database_is_migrated_and_a_newer_one_refused(target):
    from edge_monitor.historian.database import Connection, _open_postgres, _open_sqlite
    raw = _open_sqlite(target) if target.dialect == "sqlite" else _open_postgres(target)
    old = Connection(raw, target)
    with old.transaction():                       # a database made by the first release: version 1 only
        from edge_monitor.historian.migrations import version_table
        old.run(version_table(old.dialect))
        for statement in MIGRATIONS[0].sql(old.dialect):
            old.run(statement)
        old.run("INSERT INTO schema_version VALUES (1, 'v1', '2026-11-01T00:00:00Z')")
    insert_rows_v1 = ("INSERT INTO records (robot, joint, kind, ident, cycle, utc, at, day, received, stored, body) "
                      "VALUES ('r1', 0, 'symptom', '0/1/x', 1, NULL, 1.0, 0, 1.0, 1.0, '{}')")
    with old.transaction():
        old.run(insert_rows_v1)
    old.close()
    conn = connect(target)
    try:
        assert schema_version(conn) == LATEST_VERSION and count(conn) == 1
        with conn.transaction():
            conn.run("INSERT INTO schema_version VALUES (?, 'from the future', 'x')", (LATEST_VERSION + 1,))
    finally:
        conn.close()
    with pytest.raises(SchemaTooNew, match="newer than this historian knows"):
        connect(target)


def test_records_that_cannot_be_stored_say_why():
    good = symptom("r1", 0, 1)
    cases = {
        "robot_mismatch": ("symptom", "r2", 0, good), "joint_mismatch": ("symptom", "r1", 1, good),
        "cycle": ("symptom", "r1", 0, {**good, "cycle": "7"}), "not_an_object": ("symptom", "r1", 0, [1]),
        "kind": ("state", "r1", 0, good), "robot": ("symptom", "a/b", 0, good),
        "too_large": ("symptom", "r1", 0, {**good, "pad": "x" * (1 << 20)}),
    }
    for reason, (kind, robot, joint, record) in cases.items():
        made = row_of(kind, robot, joint, record, START)
        assert isinstance(made, Rejection) and made.reason == reason, (reason, made)


def test_a_hostile_jsonl_file_is_read_as_far_as_it_goes(conn, tmp_path):
    path = tmp_path / "bad.jsonl"
    good = write_jsonl(tmp_path / "good.jsonl", [symptom("r1", 0, c) for c in range(3)]).read_bytes()
    path.write_bytes(b"not json\n[1, 2]\n" + b"{" * 100_000 + b"\n" + b'{"kind": "health"}\n'
                     + b"x" * (2 << 20) + b"\n" + good + b'{"robot": "r1", "joint": 0, "cycle"')
    report = import_files(conn, [str(path), str(tmp_path / "missing.jsonl"), str(tmp_path)])
    assert report.stored == 6 and sum(report.bad_lines.values()) == 6 and len(report.unreadable) == 2
    assert report.examples[0].endswith(":1: not JSON")


def test_a_dataclass_row_is_what_the_database_gets():
    row = row_of("symptom", "r1", 0, symptom("r1", 0, 1, prognosis=prognosis(3.0)), START)
    assert not isinstance(row, Rejection)
    assert dataclasses.asdict(row)["days_median"] == 3.0 and row.ident == "0/1/2026-11-18T11:07:10.000Z"


def test_history_reads_only_a_history_database_and_says_when_one_is_damaged(tmp_path, capsys):
    """`history --db` only reads: another SQLite file is refused and left as it was (it was once given the
    historian's tables and WAL mode); a stored record that no longer parses is "damaged" (exit 1), not a
    traceback; over Zenoh the same failure is the historian's (exit 1), not the question's (exit 2)."""
    import hashlib
    import sqlite3

    import edge_monitor.cli
    from edge_monitor.historian.client import HistoryRefused, HistoryUnavailable, zenoh_asker

    other = tmp_path / "other.db"
    with sqlite3.connect(other) as raw:
        raw.execute("CREATE TABLE foo (x)")
    before = hashlib.sha256(other.read_bytes()).hexdigest()
    assert edge_monitor.cli.main(["history", "--db", str(other), "--fleet"]) == 1
    assert "not a history database" in capsys.readouterr().err
    assert hashlib.sha256(other.read_bytes()).hexdigest() == before and not (tmp_path / "other.db-wal").exists()

    damaged = tmp_path / "plant.db"
    from edge_monitor.historian.db_url import parse_db
    conn = connect(parse_db(str(damaged)))
    insert_rows(conn, symptoms_with_friction([symptom("r1", 0, 1)]))
    for table in ("records", "joints"):            # what a flipped page leaves: JSON cut short
        conn.run(f"UPDATE {table} SET body = '{{\"robot\": ' ")
    conn.close()
    for question in (["--fleet"], ["--kind", "symptom"]):
        assert edge_monitor.cli.main(["history", "--db", str(damaged), *question]) == 1
        err = capsys.readouterr().err
        assert "damaged" in err and "Traceback" not in err

    class Reply:
        def __init__(self, body):
            self.ok, self.err = None, type("Err", (), {"payload": type("P", (), {"to_string": lambda s: body})()})()

    class Session:
        def __init__(self, body):
            self.body = body

        def get(self, _selector, timeout):
            return [Reply(self.body)]

    query = HistoryQuery(what="fleet")
    with pytest.raises(HistoryUnavailable, match="damaged"):
        zenoh_asker(Session('{"error": "the history is damaged", "refused": false}'))(query)
    with pytest.raises(HistoryRefused):
        zenoh_asker(Session('{"error": "unknown parameter x"}'))(query)     # an older historian: a refusal
