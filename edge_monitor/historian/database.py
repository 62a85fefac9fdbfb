"""Connections to the historian's database, the same interface on SQLite and PostgreSQL.

:func:`connect` opens one :class:`Connection` (each thread of the historian has its own) and brings the
schema to the latest version (:mod:`edge_monitor.historian.migrations`). SQL is written once with ``?``
placeholders; a PostgreSQL connection turns them into psycopg's ``%s``. Errors are sorted into three
kinds the writer acts on: :class:`DatabaseUnavailable` (the server went away, the disk is full, the
file is locked, a PostgreSQL server is a read-only hot standby: keep the records, try again later),
:class:`DatabaseUnusable` (the SQLite file is damaged or read-only, the PostgreSQL data corrupt: no retry
mends that, someone must; the records not stored are lost and counted) and
:class:`RecordRefused` (this data cannot be stored: count it, go on). SQLite runs in WAL mode with
``synchronous=FULL``: a committed batch survives a kill -9 of the historian and a power cut.
"""

from __future__ import annotations

import json
import logging
import sqlite3
from contextlib import closing, contextmanager
from pathlib import Path
from typing import Any, Iterator, Sequence

from edge_monitor.historian.db_url import POSTGRESQL, SQLITE, DbTarget
from edge_monitor.historian.migrations import pending, version_table
from edge_monitor.records import utc_now

log = logging.getLogger(__name__)

_SQLITE_READONLY, _SQLITE_CORRUPT, _SQLITE_NOTADB = 8, 11, 26     # SQLite's primary result codes
_SQLITE_READONLY_DBMOVED = 8 | 4 << 8   # the file was moved or deleted while open: a new connection mends it
BUSY_TIMEOUT_MS = 10_000              # how long SQLite waits for another writer (a second historian)
CONNECT_TIMEOUT_S = 5                 # PostgreSQL connection timeout
_MIGRATION_LOCK = 0x6A776D48          # PostgreSQL advisory lock id of the migrations ("jwmH")


class DatabaseError(RuntimeError):
    """A database problem, said in one line with what to do."""


class DatabaseUnavailable(DatabaseError):
    """The database cannot take writes now (server down, disk full, locked): retry later, keep the data."""


class DatabaseStandby(DatabaseUnavailable):
    """A PostgreSQL server that takes no writes now (SQLSTATE 25006: a hot standby in recovery, as during a
    failover, or ``default_transaction_read_only``): an outage, retried; not a read-only SQLite file."""


class DatabaseUnusable(DatabaseError):
    """The database cannot take writes until someone repairs it: never retried as an outage."""


class DatabaseDamaged(DatabaseUnusable):
    """The database file is corrupt ("database disk image is malformed", "file is not a database")."""


class DatabaseReadOnly(DatabaseUnusable):
    """The database file (or its folder, its -wal/-shm files) cannot be written by this user."""


class RecordRefused(DatabaseError):
    """The database refuses this data (a value it cannot hold): count it and go on."""


class DriverMissing(DatabaseError):
    """PostgreSQL was asked for but psycopg is not installed."""


def stored_record(body: str) -> dict[str, Any]:
    """A record as the database keeps it (its JSON text), or DatabaseError if that text is damaged."""
    try:
        record = json.loads(body)
    except (ValueError, TypeError) as exc:
        raise DatabaseError(f"the history database is damaged: a stored record does not parse ({exc}); restore "
                            "it from a backup, or rebuild it with `edge-monitor historian import` of the agents' "
                            "JSONL files") from None
    if not isinstance(record, dict):
        raise DatabaseError("the history database is damaged: a stored record is not a JSON object; restore it "
                            "from a backup")
    return record


def _psycopg() -> Any:
    try:
        import psycopg
    except ImportError:
        raise DriverMissing("PostgreSQL needs psycopg 3: pip install 'joint-wear-monitor[historian-pg]' "
                            "(or psycopg[binary])") from None
    return psycopg


class Connection:
    """One database connection: ``rows``/``run`` with ``?`` placeholders, ``transaction()`` around writes."""

    def __init__(self, raw: Any, target: DbTarget) -> None:
        self.raw = raw
        self.target = target
        self.dialect = target.dialect

    def sql(self, text: str) -> str:
        return text if self.dialect == SQLITE else text.replace("%", "%%").replace("?", "%s")

    def run(self, text: str, params: Sequence[Any] = ()) -> int:
        """Execute one statement; the number of rows it changed."""
        with self._errors():
            cursor = self.raw.execute(self.sql(text), tuple(params))
            return int(cursor.rowcount)

    def rows(self, text: str, params: Sequence[Any] = ()) -> list[tuple]:
        with self._errors():
            return list(self.raw.execute(self.sql(text), tuple(params)).fetchall())

    @contextmanager
    def transaction(self, write: bool = True) -> Iterator["Connection"]:
        """One transaction; SQLite takes the write lock at its start (``BEGIN IMMEDIATE``) when ``write``."""
        with self._errors():
            if self.dialect == SQLITE:
                self.raw.execute("BEGIN IMMEDIATE" if write else "BEGIN")
        try:
            yield self
        except BaseException:
            self._rollback()
            raise
        with self._errors():
            self.raw.commit() if self.dialect == POSTGRESQL else self.raw.execute("COMMIT")

    def _rollback(self) -> None:
        try:
            if self.dialect == POSTGRESQL:
                self.raw.rollback()
            elif self.raw.in_transaction:
                self.raw.execute("ROLLBACK")
        except Exception as exc:   # the connection may be gone: nothing to roll back
            log.debug("rollback failed: %s", exc)

    @contextmanager
    def _errors(self) -> Iterator[None]:
        """Database errors as :class:`DatabaseUnavailable` / :class:`DatabaseUnusable` /
        :class:`RecordRefused`, in one line."""
        try:
            yield
        except sqlite3.IntegrityError as exc:
            raise RecordRefused(f"SQLite refused a value: {exc}") from exc
        except sqlite3.DatabaseError as exc:
            path = Path(str(self.target.path))
            unusable = sqlite_unusable(exc, path)
            if unusable is not None:
                raise unusable from exc
            text = str(exc)
            hint = ("; free space on the disk (records wait in memory)" if "full" in text
                    else "; another program holds the file" if "locked" in text else "")
            raise DatabaseUnavailable(f"SQLite {path}: {text}{hint}") from exc
        except Exception as exc:
            if self.dialect != POSTGRESQL:
                raise
            errors = _psycopg()
            if isinstance(exc, (errors.errors.DataError, errors.errors.IntegrityError)):
                raise RecordRefused(f"PostgreSQL refused a value: {_one_line(exc)}") from exc
            if isinstance(exc, (errors.errors.DataCorrupted, errors.errors.IndexCorrupted)):
                raise DatabaseDamaged(f"{self.target.describe()} is damaged ({_one_line(exc)}): the historian "
                                      "stopped writing into it; repair it (REINDEX, or restore from a backup), "
                                      "then start the historian again") from exc
            if isinstance(exc, errors.errors.ReadOnlySqlTransaction):
                raise DatabaseStandby(f"{self.target.describe()} takes no writes ({_one_line(exc)}): the server "
                                      "is a hot standby in recovery (as during a failover) or has "
                                      "default_transaction_read_only on; if that lasts, point --db at the primary "
                                      "or turn default_transaction_read_only off") from exc
            if isinstance(exc, (errors.OperationalError, errors.InterfaceError)):
                raise DatabaseUnavailable(f"{self.target.describe()}: {_one_line(exc)}") from exc
            raise

    def close(self) -> None:
        try:
            self.raw.close()
        except Exception as exc:
            log.debug("closing the database connection: %s", exc)


def sqlite_unusable(exc: sqlite3.Error, path: Path) -> DatabaseUnusable | None:
    """``exc`` as :class:`DatabaseDamaged` / :class:`DatabaseReadOnly` with what to do, or None when it is
    none of these (a locked file, a full disk: an outage, retried)."""
    code = getattr(exc, "sqlite_errorcode", None)
    primary = code & 0xFF if isinstance(code, int) else None
    text = _one_line(exc)
    if primary in (_SQLITE_CORRUPT, _SQLITE_NOTADB) or "malformed" in text or "not a database" in text:
        return DatabaseDamaged(f"SQLite {path} is damaged ({text}): restore it from a backup, or recover what it "
                               f"holds with `sqlite3 {path} \".recover\" | sqlite3 recovered.db` and use that file; "
                               "`edge-monitor historian import` of the agents' JSONL files fills what is missing")
    if (primary == _SQLITE_READONLY and code != _SQLITE_READONLY_DBMOVED) or "readonly database" in text:
        return DatabaseReadOnly(f"SQLite {path} is read-only for this user ({text}): let the historian's user "
                                "write the file, its folder and its -wal/-shm files (check owner and mode), then "
                                "start the historian again")
    return None


def _one_line(exc: BaseException) -> str:
    return " ".join(str(exc).split())[:300]


def connect(target: DbTarget, migrate: bool = True, create: bool = True) -> Connection:
    """A new connection to ``target`` with its schema at the latest version (``migrate``); ``create``: a
    SQLite file that does not exist is made (else: DatabaseUnavailable, for commands that only read). An
    existing SQLite file must be a history database (or hold no table yet): another program's database
    is refused, never given the historian's tables."""
    if target.dialect == SQLITE and (not create or Path(str(target.path)).exists()):
        _check_history_file(Path(str(target.path)), empty_ok=create)
    conn = Connection(_open_sqlite(target) if target.dialect == SQLITE else _open_postgres(target), target)
    if migrate:
        try:
            migrate_schema(conn)
        except BaseException:
            conn.close()
            raise
    return conn


def _check_history_file(path: Path, empty_ok: bool = False) -> None:
    """DatabaseUnavailable unless ``path`` is a SQLite file the historian made, or (``empty_ok``) one without
    any table yet; checked read-only, so that no command turns another program's SQLite file into a
    history database."""
    if not path.is_file():
        raise DatabaseUnavailable(f"no history database at {path}: fix --db, or start `edge-monitor historian "
                                  f"--db {path}` first")
    try:
        with closing(sqlite3.connect(f"{path.resolve().as_uri()}?mode=ro", uri=True)) as raw:
            tables = {name for (name,) in raw.execute("SELECT name FROM sqlite_master WHERE type = 'table'")}
    except sqlite3.Error as exc:
        unusable = sqlite_unusable(exc, path)
        if unusable is not None:
            raise unusable from exc
        raise DatabaseUnavailable(f"cannot read SQLite {path}: {exc}; is it a history database?") from exc
    if "schema_version" not in tables and not (empty_ok and not tables):
        raise DatabaseUnavailable(f"{path} is a SQLite database but not a history database (no schema_version "
                                  "table): fix --db")


def _open_sqlite(target: DbTarget) -> sqlite3.Connection:
    path = Path(str(target.path))
    raw = None
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        raw = sqlite3.connect(str(path), isolation_level=None, check_same_thread=False,
                              timeout=BUSY_TIMEOUT_MS / 1000)
        raw.execute("PRAGMA journal_mode=WAL")
        raw.execute("PRAGMA synchronous=FULL")
        raw.execute(f"PRAGMA busy_timeout={BUSY_TIMEOUT_MS}")
        if target.max_page_count:
            raw.execute(f"PRAGMA max_page_count={int(target.max_page_count)}")
    except (OSError, sqlite3.Error) as exc:
        if raw is not None:
            raw.close()
        unusable = sqlite_unusable(exc, path) if isinstance(exc, sqlite3.Error) else None
        if unusable is not None:
            raise unusable from exc
        raise DatabaseUnavailable(f"cannot open SQLite {path}: {exc}; check the path and its permissions") from exc
    return raw


def check_writable(conn: Connection) -> None:
    """SQLite: :class:`DatabaseReadOnly` now, not at the first batch (a write that changes nothing; opening
    and reading a read-only file succeed)."""
    if conn.dialect == SQLITE:
        with conn.transaction():
            conn.run("DELETE FROM schema_version WHERE version < 0")


def _open_postgres(target: DbTarget) -> Any:
    psycopg = _psycopg()
    try:
        return psycopg.connect(str(target.url), autocommit=False, connect_timeout=CONNECT_TIMEOUT_S,
                               application_name="edge-monitor historian")
    except psycopg.Error as exc:
        text = _one_line(exc)
        hint = ("; give the password through PGPASSWORD, PGPASSFILE (~/.pgpass) or --db-url-file"
                if "password" in text else "; is the server running, and the URL right?")
        raise DatabaseUnavailable(f"cannot connect to {target.describe()}: {text}{hint}") from exc


def schema_version(conn: Connection) -> int:
    """The latest migration applied (0: a new database)."""
    with conn.transaction(write=False):
        conn.run(version_table(conn.dialect))
        found = conn.rows("SELECT MAX(version) FROM schema_version")
    return int(found[0][0] or 0)


def migrate_schema(conn: Connection) -> list[int]:
    """Apply the pending migrations under the migration lock; the versions applied (logged)."""
    with conn.transaction():
        if conn.dialect == POSTGRESQL:
            conn.rows("SELECT pg_advisory_xact_lock(?)", (_MIGRATION_LOCK,))
        conn.run(version_table(conn.dialect))
        current = int(conn.rows("SELECT MAX(version) FROM schema_version")[0][0] or 0)
        applied = []
        for migration in pending(current):
            for statement in migration.sql(conn.dialect):
                conn.run(statement)
            conn.run("INSERT INTO schema_version (version, description, applied_utc) VALUES (?, ?, ?)",
                     (migration.version, migration.description, utc_now()))
            applied.append(migration.version)
    if applied:
        log.info("%s: schema migrated to version %d (applied %s)", conn.target.describe(), applied[-1],
                 ", ".join(map(str, applied)))
    return applied
