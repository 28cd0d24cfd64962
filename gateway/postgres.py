"""PostgreSQL for the state that shards share (the job queue, the machines' leases): the one psycopg module.

Everything else talks to the database through `Database` and `Transaction`
here, so psycopg's errors become the gateway's own (`error`, a StoreError or a
subclass, with the URL shown without its password) and psycopg's types stay in
this file. One connection per `Database`, shared by threads under a lock, like
the SQLite files (gateway/sqlite_file.py); autocommit, with an explicit
transaction per operation. A connection the server dropped (a restart) is
opened again by the next operation, so a queue waits for its database instead
of dying with it; one that has been idle for `ping_after` seconds is tried
first (a round trip), so that an idle gateway finds a restarted server without
failing the operation that comes next.

Schemas are versioned per component in `schema_versions`: `migrate()` applies
the steps a database lacks, under an advisory lock so that two gateways that
start together do not both migrate, and refuses a database that a newer
gateway has migrated further than this one knows.

Passwords come from the URL or from libpq's environment (PGPASSWORD,
~/.pgpass, PGSERVICE…), which psycopg reads itself.
"""

from __future__ import annotations

import threading
import time
import zlib
from collections.abc import Iterator, Sequence
from contextlib import contextmanager
from typing import Any, Self
from urllib.parse import urlsplit, urlunsplit

import psycopg
from psycopg.rows import dict_row

from gateway.errors import GatewayError, StoreError

SCHEMES = ("postgresql", "postgres")
Row = dict[str, Any]


def is_postgres_url(text: str) -> bool:
    return urlsplit(text).scheme in SCHEMES


def redact(url: str) -> str:
    """The URL as messages and logs show it: the password replaced by ***."""
    parts = urlsplit(url)
    if parts.password is None:
        return url
    host = parts.hostname or ""
    if parts.port is not None:
        host = f"{host}:{parts.port}"
    user = f"{parts.username}:***@" if parts.username else ":***@"
    return urlunsplit((parts.scheme, user + host, parts.path, parts.query, parts.fragment))


class Transaction:
    """One transaction's statements. Rows come back as dicts; errors as the database's error class."""

    def __init__(self, cursor: psycopg.Cursor[Row], database: Database) -> None:
        self._cur = cursor
        self._database = database

    def execute(self, sql: str, params: Sequence[Any] = ()) -> None:
        with self._database.translated():
            self._cur.execute(
                sql.encode(), params
            )  # bytes: a query string psycopg's LiteralString type lets through

    def all(self, sql: str, params: Sequence[Any] = ()) -> list[Row]:
        with self._database.translated():
            self._cur.execute(sql.encode(), params)
            return self._cur.fetchall()

    def one(self, sql: str, params: Sequence[Any] = ()) -> Row | None:
        with self._database.translated():
            self._cur.execute(sql.encode(), params)
            return self._cur.fetchone()

    def scalar(self, sql: str, params: Sequence[Any] = ()) -> Any:
        row = self.one(sql, params)
        return None if row is None else next(iter(row.values()))


class Database:
    """A connection to one PostgreSQL database, for the component that names itself `noun` in messages."""

    def __init__(
        self,
        url: str,
        *,
        noun: str,
        error: type[GatewayError] = StoreError,
        connect_timeout: float = 10.0,
        application_name: str = "cnc-gateway",
        idle_in_transaction: float = 5.0,
        ping_after: float = 5.0,
    ) -> None:
        self.url = url
        self.noun = noun
        self.error = error
        self.connect_timeout = connect_timeout
        self.application_name = application_name
        # A process paused inside a transaction (SIGSTOP, a stalled VM) would hold its row locks, and so
        # block a takeover, for as long as it sleeps: the server ends such a session after this long.
        self.idle_in_transaction = idle_in_transaction
        self.ping_after = ping_after
        self._used = 0.0  # time.monotonic() of the last transaction
        self._conn: psycopg.Connection[Row] | None = None
        self._lock = threading.RLock()

    def __str__(self) -> str:
        return redact(self.url)

    def open(self) -> Self:
        with self._lock:
            self._connection()
        return self

    def close(self) -> None:
        with self._lock:
            if self._conn is not None:
                self._conn.close()
                self._conn = None

    def __enter__(self) -> Self:
        return self.open()

    def __exit__(self, *exc_info: object) -> None:
        self.close()

    @contextmanager
    def translated(self) -> Iterator[None]:
        """psycopg's errors as `self.error`, naming the database (without its password)."""
        try:
            yield
        except psycopg.errors.LockNotAvailable as exc:
            raise self.error(f"the {self.noun} at {self} is busy: {_first_line(exc)}") from None
        except psycopg.OperationalError as exc:
            raise self.error(f"cannot reach the {self.noun} at {self}: {_first_line(exc)}") from None
        except psycopg.Error as exc:
            raise self.error(f"the {self.noun} at {self} failed: {_first_line(exc)}") from None

    def _connection(self) -> psycopg.Connection[Row]:
        conn = self._conn
        if conn is not None and not conn.closed and not conn.broken:
            now = time.monotonic()
            if now - self._used < self.ping_after:
                return conn
            try:
                conn.execute(b"SELECT 1")
                return conn
            except psycopg.Error:  # dropped while idle (a restart): open another below
                conn.close()
        self._conn = None
        with self.translated():
            conn = psycopg.connect(
                self.url,
                autocommit=True,
                row_factory=dict_row,
                connect_timeout=max(1, round(self.connect_timeout)),
                application_name=self.application_name,
                # UTC, as the SQLite stores write times: a record's times never depend on the server's zone
                options=f"-c idle_in_transaction_session_timeout={round(self.idle_in_transaction * 1000)}"
                " -c TimeZone=UTC",
            )
        self._conn = conn
        return conn

    @contextmanager
    def transaction(self) -> Iterator[Transaction]:
        """One transaction (READ COMMITTED), committed when the block ends, rolled back if it raises."""
        with self._lock:
            conn = self._connection()
            self._used = time.monotonic()
            try:
                with conn.transaction(), conn.cursor() as cur:
                    yield Transaction(cur, self)
            except psycopg.Error as exc:  # the commit itself, or a statement outside Transaction
                with self.translated():
                    raise exc from None

    def migrate(self, component: str, steps: Sequence[str]) -> int:
        """Bring `component`'s tables to version len(steps), applying the steps it lacks, in one transaction.

        A database a newer gateway has migrated further is refused (this gateway would misread it)."""
        target = len(steps)
        with self.transaction() as tx:
            tx.execute("SELECT pg_advisory_xact_lock(%s)", (_lock_key(component),))
            tx.execute(
                "CREATE TABLE IF NOT EXISTS schema_versions"
                " (component TEXT PRIMARY KEY, version INTEGER NOT NULL, migrated_at TIMESTAMPTZ NOT NULL)"
            )
            found = tx.scalar("SELECT version FROM schema_versions WHERE component = %s", (component,))
            version = int(found or 0)
            if version > target:
                raise self.error(
                    f"the {self.noun} at {self} has schema {version}, from a newer cnc-gateway"
                    f" (this one knows schema {target}): upgrade this gateway, or give it another database"
                )
            for step in steps[version:]:
                tx.execute(step)
            if version < target:
                tx.execute(
                    "INSERT INTO schema_versions (component, version, migrated_at) VALUES (%s, %s, now())"
                    " ON CONFLICT (component) DO UPDATE SET version = EXCLUDED.version,"
                    " migrated_at = EXCLUDED.migrated_at",
                    (component, target),
                )
        return target


def _lock_key(component: str) -> int:
    """A stable advisory-lock key per component (a signed 32-bit number, which pg_advisory_lock takes)."""
    return zlib.crc32(f"cnc-gateway:{component}".encode()) - 2**31


def _first_line(exc: BaseException) -> str:
    text = str(exc).strip()
    return text.splitlines()[0] if text else type(exc).__name__
