"""A throwaway PostgreSQL server in a temporary folder, on a loopback port, for tests, benchmarks and
fault runs (``initdb`` + ``pg_ctl``; PostgreSQL 15 binaries are looked for on PATH and under
/usr/lib/postgresql/*/bin).

PostgreSQL refuses to run as root. Run as root (CI here is), the server runs as an unprivileged user —
``postgres`` if the system has one, else ``nobody`` — through ``runuser``; the data folder is made in
/tmp (world-traversable) and given to that user. Authentication is scram-sha-256 over TCP on 127.0.0.1
with a generated password: clients get it the way the historian wants credentials, from the
environment (``PGPASSWORD``) or a password file (``passfile``), never in a URL.

    with ThrowawayPostgres() as pg:      # or: pg = ThrowawayPostgres(); reason = pg.unavailable()
        url = pg.url                    # postgresql://historian@127.0.0.1:PORT/historian
        env = pg.client_env()           # PGPASSWORD for subprocesses
"""

from __future__ import annotations

import glob
import os
import pwd
import secrets
import shutil
import signal
import socket
import subprocess
import tempfile
import time
from pathlib import Path

USER = "historian"
START_TIMEOUT_S = 60.0


def _binaries() -> Path | None:
    found = shutil.which("pg_ctl")
    if found:
        return Path(found).parent
    candidates = sorted(glob.glob("/usr/lib/postgresql/*/bin/pg_ctl"), reverse=True)
    return Path(candidates[0]).parent if candidates else None


def _free_port() -> int:
    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        return int(sock.getsockname()[1])


class ThrowawayPostgres:
    """Start with :meth:`start` (or ``with``); :meth:`unavailable` says why it cannot run here (or None)."""

    def __init__(self, fsync: bool = True) -> None:
        self.bin = _binaries()
        self.fsync = fsync
        self.port = 0
        self.password = secrets.token_urlsafe(18)
        self.folder: Path | None = None
        self.run_as: str | None = None
        self._started = False

    def unavailable(self) -> str | None:
        """Why no server can be started here (None: it can)."""
        if self.bin is None or not (self.bin / "initdb").exists():
            return ("PostgreSQL server binaries (initdb, pg_ctl) not found on PATH or under /usr/lib/postgresql/*/bin; "
                    "install the postgresql package")
        try:
            import psycopg  # noqa: F401
        except ImportError:
            return "psycopg is not installed (pip install 'joint-wear-monitor[historian-pg]')"
        if os.geteuid() == 0:
            if shutil.which("runuser") is None:
                return "running as root and runuser is missing: PostgreSQL refuses to run as root"
            if self._unprivileged_user() is None:
                return "running as root and no unprivileged user (postgres, nobody) to run PostgreSQL as"
        return None

    @staticmethod
    def _unprivileged_user() -> str | None:
        for name in ("postgres", "nobody"):
            try:
                pwd.getpwnam(name)
                return name
            except KeyError:
                continue
        return None

    @property
    def url(self) -> str:
        return f"postgresql://{USER}@127.0.0.1:{self.port}/{USER}"

    def client_env(self) -> dict[str, str]:
        """The environment of a client process: this one's plus ``PGPASSWORD``."""
        return {**os.environ, "PGPASSWORD": self.password}

    def write_passfile(self, path: Path) -> Path:
        """A libpq password file (mode 600) for this server."""
        path.write_text(f"127.0.0.1:{self.port}:*:{USER}:{self.password}\n")
        path.chmod(0o600)
        return path

    def _command(self, *argv: str) -> list[str]:
        return ["runuser", "-u", str(self.run_as), "--", *argv] if self.run_as else list(argv)

    def start(self) -> "ThrowawayPostgres":
        reason = self.unavailable()
        if reason:
            raise RuntimeError(reason)
        self.folder = Path(tempfile.mkdtemp(prefix="historian-pg-", dir="/tmp"))
        data, pwfile = self.folder / "data", self.folder / "pw"
        pwfile.write_text(self.password + "\n")
        if os.geteuid() == 0:
            self.run_as = self._unprivileged_user()
            entry = pwd.getpwnam(str(self.run_as))
            for path in (self.folder, pwfile):
                os.chown(path, entry.pw_uid, entry.pw_gid)
        self._run("initdb", "-D", str(data), "-U", USER, "--auth=scram-sha-256", f"--pwfile={pwfile}",
                  "-E", "UTF8", "--locale=C")
        pwfile.unlink()
        self.port = _free_port()
        self._pg_ctl_start()
        self._started = True
        import psycopg
        with psycopg.connect(f"host=127.0.0.1 port={self.port} user={USER} dbname=postgres password={self.password}",
                             autocommit=True) as conn:
            conn.execute(f"CREATE DATABASE {USER}")
        return self

    def _pg_ctl_start(self) -> None:
        assert self.folder is not None
        options = (f"-c listen_addresses=127.0.0.1 -c port={self.port} -c unix_socket_directories={self.folder} "
                   f"-c fsync={'on' if self.fsync else 'off'} -c max_connections=50")
        self._run("pg_ctl", "-D", str(self.folder / "data"), "-o", options, "-l", str(self.folder / "log"), "-w",
                  "-t", str(int(START_TIMEOUT_S)), "start")

    def _run(self, tool: str, *args: str) -> None:
        assert self.bin is not None
        done = subprocess.run(self._command(str(self.bin / tool), *args), capture_output=True, text=True,
                              timeout=START_TIMEOUT_S * 2)
        if done.returncode != 0:
            raise RuntimeError(f"{tool} failed ({done.returncode}): {(done.stderr or done.stdout)[-800:]}")

    def pid(self) -> int | None:
        """The postmaster's process id (for kill -9 in fault runs)."""
        try:
            assert self.folder is not None
            return int((self.folder / "data" / "postmaster.pid").read_text().split()[0])
        except (OSError, ValueError, IndexError, TypeError):
            return None

    def kill(self) -> None:
        """kill -9 the server (a crash); :meth:`restart` brings it back with its data."""
        pid = self.pid()
        if pid:
            os.kill(pid, signal.SIGKILL)
            deadline = time.monotonic() + 10
            while time.monotonic() < deadline:
                try:
                    os.kill(pid, 0)
                except ProcessLookupError:
                    break
                time.sleep(0.05)

    def restart(self) -> None:
        """Start again after :meth:`kill` (crash recovery replays its WAL)."""
        assert self.folder is not None
        (self.folder / "data" / "postmaster.pid").unlink(missing_ok=True)
        self._pg_ctl_start()

    def stop(self) -> None:
        if self._started and self.folder is not None:
            try:
                self._run("pg_ctl", "-D", str(self.folder / "data"), "-m", "immediate", "-w", "stop")
            except (RuntimeError, subprocess.TimeoutExpired):
                self.kill()
            self._started = False
        if self.folder is not None:
            shutil.rmtree(self.folder, ignore_errors=True)
            self.folder = None

    def __enter__(self) -> "ThrowawayPostgres":
        return self.start()

    def __exit__(self, *_exc: object) -> None:
        self.stop()
