"""Records and questions a hostile peer sends the historian: a fault of another robot's joint is never
closed or changed (refused as ``fault_mismatch``, and the ``faults`` upsert matches robot and joint too),
records without the fields their schema requires or with a wall time that is no time or far in the
future are refused by reason, the robot name ``history`` is reserved, another program's SQLite file is
refused, a cursor past the databases' integers is a refusal; the legitimate records still go in."""

from __future__ import annotations

import dataclasses
import json
import sqlite3

import jsonschema
import pytest
from historian_support import (  # noqa: F401 (postgres is a fixture)
    ENGINES,
    START,
    alarm,
    fresh_database,
    postgres,
    symptom,
)

from edge_monitor.historian.database import DatabaseUnavailable, connect
from edge_monitor.historian.db_url import parse_db
from edge_monitor.historian.identity import Rejection, Row, row_of
from edge_monitor.historian.queries import answer
from edge_monitor.historian.query_spec import MAX_RECORD_ID, Cursor, HistoryQuery, QueryError, query_of
from edge_monitor.historian.record_checks import MAX_AHEAD_S
from edge_monitor.historian.writes import insert_rows
from edge_monitor.records import utc_text
from edge_monitor.schemas import load_schema
from edge_monitor.sinks.keys import check_robot_name


@pytest.fixture(params=ENGINES)
def conn(request, tmp_path, monkeypatch):
    connection = connect(fresh_database(request.param, tmp_path, request, monkeypatch))
    yield connection
    connection.close()


def _row(kind: str, robot: str, joint: int | None, record: dict, received: float = START) -> Row:
    made = row_of(kind, robot, joint, record, received)
    assert isinstance(made, Row), made
    return made


def _reason(kind: str, robot: str, joint: int | None, record: object, received: float = START) -> str | None:
    made = row_of(kind, robot, joint, record, received)
    return made.reason if isinstance(made, Rejection) else None


def _fault(conn, fault: str) -> tuple:
    return conn.rows("SELECT robot, joint, state, is_open, cycle FROM faults WHERE fault = ?", (fault,))[0]


# -- defect 1: a fault belongs to its robot and joint ------------------------------------------------------


def test_an_alarm_naming_another_joints_fault_is_refused_and_the_owners_records_still_count():
    hijack = {**alarm("r8", 0, 99, "cleared", 99, open_=False), "fault": "r9/0/1"}
    assert _reason("alarm", "r8", 0, hijack) == "fault_mismatch"
    assert _reason("alarm", "r9", 1, {**alarm("r9", 1, 5, "cleared", 1), "fault": "r9/0/1"}) == "fault_mismatch"
    assert _reason("alarm", "r9", 0, {**alarm("r9", 0, 5, "cleared", 1), "fault": "r9/0"}) == "fault_mismatch"
    assert _reason("alarm", "r9", 0, {**alarm("r9", 0, 5, "cleared", 1), "fault": 7}) == "fault_mismatch"
    assert _reason("alarm", "r9", 0, {**alarm("r9", 0, 5, "raised", 5), "fault": "r9/0/" + "x" * 300}) \
        == "fault_mismatch"
    assert _row("alarm", "r9", 0, alarm("r9", 0, 5, "cleared", 1)).fault == "r9/0/1"
    legacy = {k: v for k, v in alarm("r9", 0, 5, "raised", 5).items() if k not in ("fault", "open")}
    assert _row("alarm", "r9", 0, legacy).fault == "r9/0/5/wear"       # before faults: a fault of its own


def test_the_faults_table_is_only_changed_by_the_faults_own_robot_and_joint(conn):
    insert_rows(conn, [_row("alarm", "r9", 0, alarm("r9", 0, 1, "raised", 1))])
    assert _fault(conn, "r9/0/1") == ("r9", 0, "raised", 1, 1)
    # a row that names another robot's fault (as only a bug could make now): stored as its own record,
    # never the newest state of r9's fault
    forged = _row("alarm", "r8", 0, alarm("r8", 0, 99, "cleared", 1, open_=False))
    insert_rows(conn, [dataclasses.replace(forged, fault="r9/0/1")])
    assert _fault(conn, "r9/0/1") == ("r9", 0, "raised", 1, 1)
    insert_rows(conn, [_row("alarm", "r9", 0, alarm("r9", 0, 9, "cleared", 1, open_=False))])
    assert _fault(conn, "r9/0/1") == ("r9", 0, "cleared", 0, 9)
    assert answer(conn, HistoryQuery(what="alarms"))["count"] == 0


# -- defect 3: the fields a record's schema requires, a real wall time, a reserved robot name -------------


@pytest.mark.parametrize("record, reason", [
    ({"cycle": 7}, "missing_field"),
    ({**symptom("r9", 0, 10), "schema": 2}, "bad_field"),
    ({**symptom("r9", 0, 10), "utc": "yesterday at noon"}, "utc"),
    ({**symptom("r9", 0, 10), "utc": 5}, "utc"),
    ({**symptom("r9", 0, 10), "utc": "0001-01-01T00:00:00Z"}, "utc"),
    ({**symptom("r9", 0, 10), "utc": "9999-12-31T23:59:59.999Z"}, "utc_ahead"),
    ({**symptom("r9", 0, 10), "alarm": "no"}, "bad_field"),
    ({**symptom("r9", 0, 10), "kind": "alarm"}, "bad_field"),
    ({k: v for k, v in symptom("r9", 0, 10).items() if k != "wear"}, "missing_field"),
])
def test_a_symptom_without_what_its_schema_requires_is_refused_by_reason(record, reason):
    assert _reason("symptom", "r9", 0, record) == reason


def test_an_alarm_with_a_wrong_open_flag_or_state_is_refused():
    good = alarm("r9", 0, 2, "raised", 2)
    assert _reason("alarm", "r9", 0, {**good, "open": "yes"}) == "bad_field"
    assert _reason("alarm", "r9", 0, {**good, "state": "closed"}) == "bad_field"
    assert _reason("alarm", "r9", 0, {k: v for k, v in good.items() if k != "quantity"}) == "missing_field"
    assert _reason("health", "r9", None, {"robot": "r9", "time": 1.0}) == "missing_field"
    assert isinstance(row_of("alarm", "r9", 0, good, START), Row)


def test_a_wall_time_a_little_ahead_is_stored_and_one_beyond_the_bound_is_not():
    ahead = START + MAX_AHEAD_S - 60
    assert _row("symptom", "r9", 0, symptom("r9", 0, 1, at=ahead)).at == pytest.approx(ahead)
    assert _reason("symptom", "r9", 0, symptom("r9", 0, 1, at=START + MAX_AHEAD_S + 60)) == "utc_ahead"
    assert _row("symptom", "r9", 0, {**symptom("r9", 0, 1), "utc": None}).at == START    # no wall time: arrival


def test_the_robot_name_history_is_reserved():
    with pytest.raises(ValueError, match="reserved"):
        check_robot_name("history")
    assert check_robot_name("history2") == "history2"
    assert _reason("symptom", "history", 0, symptom("history", 0, 1)) == "robot"
    with pytest.raises(QueryError, match="reserved"):
        HistoryQuery(robot="history")


def test_what_is_stored_answers_by_the_history_schema_with_the_kind_it_was_stored_as(conn):
    insert_rows(conn, [_row("symptom", "r9", 0, symptom("r9", 0, 1)), _row("alarm", "r9", 0, alarm("r9", 0, 1,
                                                                                                   "raised", 1))])
    # a record stored before these checks, claiming another kind: the kind it was stored as wins
    conn.run("UPDATE records SET body = ? WHERE kind = 'symptom'", (json.dumps({**symptom("r9", 0, 1),
                                                                                 "kind": "alarm"}),))
    for what in ("records", "alarms"):
        reply = answer(conn, HistoryQuery(what=what))
        jsonschema.validate(reply, load_schema("history"))
        assert reply["count"] >= 1
    assert sorted(r["kind"] for r in answer(conn, HistoryQuery())["records"]) == ["alarm", "symptom"]


# -- defect 4: another program's SQLite file -----------------------------------------------------------------


def test_the_historian_refuses_another_programs_sqlite_file_and_opens_its_own(tmp_path):
    other = tmp_path / "other.db"
    with sqlite3.connect(other) as raw:
        raw.execute("CREATE TABLE inventory (part TEXT)")
    with pytest.raises(DatabaseUnavailable, match="not a history database"):
        connect(parse_db(str(other)))
    with sqlite3.connect(other) as raw:
        tables = {name for (name,) in raw.execute("SELECT name FROM sqlite_master WHERE type = 'table'")}
    assert tables == {"inventory"}
    empty = tmp_path / "empty.db"
    empty.touch()                                   # an empty file (no table yet): made a history database
    for path in (empty, tmp_path / "new.db", empty):
        connect(parse_db(str(path))).close()


# -- defect 5: a cursor beyond the databases' integers ---------------------------------------------------------


def test_a_cursor_id_beyond_64_bits_is_refused_and_the_largest_one_works(tmp_path):
    with pytest.raises(QueryError, match="cursor"):
        query_of("records", {"cursor": "0:9999999999999999999"})
    with pytest.raises(QueryError, match="cursor"):
        Cursor.parse(f"0:{MAX_RECORD_ID + 1}")
    conn = connect(parse_db(str(tmp_path / "h.db")))
    try:
        insert_rows(conn, [_row("symptom", "r9", 0, symptom("r9", 0, 1))])
        page = answer(conn, query_of("records", {"cursor": f"0:{MAX_RECORD_ID}"}))
        assert page["count"] == 1 and page["records"][0]["utc"] == utc_text(START + 30)
    finally:
        conn.close()
