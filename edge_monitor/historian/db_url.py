"""Which database the historian uses: ``--db`` (a SQLite file, or ``postgresql://…``) or ``--db-url-file``.

* A path, ``sqlite:PATH`` or ``sqlite:///ABSOLUTE/PATH``: one SQLite file (WAL), created when missing.
  ``?max_page_count=N`` caps its size at N pages of 4 KiB (a full disk, for fault tests).
* ``postgresql://[user@]host[:port]/dbname[?options]`` (or ``postgres://``): PostgreSQL through psycopg 3
  (the ``historian-pg`` extra). ``host`` may be a socket folder (``?host=/run/postgresql``).

Credentials never go on the command line, where every user of the machine reads them (``ps``): a
password in ``--db`` is refused. libpq takes it from ``PGPASSWORD`` or the password file ``PGPASSFILE``
(default ``~/.pgpass``), or the whole URL comes from ``--db-url-file`` (a file only its owner may read).
"""

from __future__ import annotations

import os
import stat
from dataclasses import dataclass
from pathlib import Path
from urllib.parse import parse_qs, urlsplit

SQLITE, POSTGRESQL = "sqlite", "postgresql"
MAX_URL_FILE_BYTES = 4096


class DatabaseUrlError(ValueError):
    """A ``--db`` value or URL file that cannot be used (says what to do instead)."""


@dataclass(frozen=True)
class DbTarget:
    """A parsed database location: ``dialect`` sqlite|postgresql, ``path`` (SQLite) or ``url`` (PostgreSQL,
    possibly with a password when it came from a URL file), ``max_page_count`` (SQLite, 0: no cap)."""

    dialect: str
    path: str | None = None
    url: str | None = None
    max_page_count: int = 0

    def describe(self) -> str:
        """For logs and messages: never the password."""
        if self.dialect == SQLITE:
            return f"SQLite {self.path}"
        parts = urlsplit(self.url or "")
        netloc = parts.hostname or ""
        if parts.username:
            netloc = f"{parts.username}@{netloc}"
        if parts.port:
            netloc += f":{parts.port}"
        return f"PostgreSQL {parts.scheme}://{netloc}{parts.path}"


def parse_db(value: str, *, from_file: bool = False) -> DbTarget:
    """The target ``--db`` names. ``from_file``: the URL came from a protected file (a password is allowed)."""
    text = str(value).strip()
    if not text:
        raise DatabaseUrlError("--db is empty; give a SQLite file (plant.db) or postgresql://user@host/dbname")
    scheme = text.split(":", 1)[0].lower() if ":" in text else ""
    if scheme in ("postgresql", "postgres"):
        _refuse_password(text, from_file)
        return DbTarget(POSTGRESQL, url=text)
    if scheme == "sqlite":
        rest = text[len("sqlite:"):]
        rest = rest[2:] if rest.startswith("//") else rest
        return _sqlite(rest)
    if "://" in text:
        raise DatabaseUrlError(f"--db: unknown database scheme {scheme!r}; give a SQLite file path or "
                               "postgresql://user@host/dbname")
    return _sqlite(text)


def _sqlite(text: str) -> DbTarget:
    path, _, query = text.partition("?")
    if not path:
        raise DatabaseUrlError("--db: the SQLite URL names no file; e.g. sqlite:///var/lib/historian/plant.db")
    options = parse_qs(query, keep_blank_values=True)
    unknown = sorted(set(options) - {"max_page_count"})
    if unknown:
        raise DatabaseUrlError(f"--db: unknown SQLite option(s) {', '.join(unknown)}; only max_page_count=N")
    pages = 0
    if "max_page_count" in options:
        raw = options["max_page_count"][-1]
        if not raw.isdigit() or not 10 <= int(raw) <= 2 ** 31:
            raise DatabaseUrlError(f"--db: max_page_count={raw[:20]!r} must be a whole number 10 … 2147483648")
        pages = int(raw)
    if Path(path).is_dir():
        raise DatabaseUrlError(f"--db {path}: is a folder; give a file name such as {Path(path) / 'plant.db'}")
    return DbTarget(SQLITE, path=path, max_page_count=pages)


def _refuse_password(url: str, from_file: bool) -> None:
    if from_file:
        return
    parts = urlsplit(url)
    try:
        password = parts.password
    except ValueError:
        password = None
    if password or "password" in {k.lower() for k in parse_qs(parts.query, keep_blank_values=True)}:
        raise DatabaseUrlError("--db holds a password, which every user of this machine can read on the command "
                               "line; remove it and give it through PGPASSWORD, a password file (PGPASSFILE, "
                               "~/.pgpass) or --db-url-file FILE (mode 600)")


def read_url_file(path: str) -> DbTarget:
    """The database URL written in ``path`` (first non-empty line): a regular file of at most 4 KiB that
    neither group nor others may read (as libpq demands of a password file)."""
    try:
        info = os.stat(path)
    except OSError as exc:
        raise DatabaseUrlError(f"--db-url-file {path}: {exc.strerror}") from None
    if not stat.S_ISREG(info.st_mode) or info.st_size > MAX_URL_FILE_BYTES:
        raise DatabaseUrlError(f"--db-url-file {path}: must be a regular file of at most {MAX_URL_FILE_BYTES} bytes")
    if info.st_mode & (stat.S_IRWXG | stat.S_IRWXO):
        raise DatabaseUrlError(f"--db-url-file {path}: group or others may read it; chmod 600 {path}")
    try:
        lines = [line.strip() for line in Path(path).read_text(encoding="utf-8").splitlines()]
    except (OSError, UnicodeDecodeError) as exc:
        raise DatabaseUrlError(f"--db-url-file {path}: cannot be read ({exc})") from None
    url = next((line for line in lines if line and not line.startswith("#")), "")
    if not url:
        raise DatabaseUrlError(f"--db-url-file {path}: holds no URL")
    return parse_db(url, from_file=True)
