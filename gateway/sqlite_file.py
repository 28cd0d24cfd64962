"""The gateway's SQLite files (job queue, alarm history, audit table, MQTT backlog): one way to open them.

WAL, so that the CLI reads while the gateway writes; synchronous=FULL, so that
a committed transition survives a power cut (a file whose last commits may go
with the power says `synchronous = "NORMAL"`); a schema version in user_version,
so that a file from a newer gateway is refused instead of misread; and write
transactions taken at once (BEGIN IMMEDIATE), so that two writers never
deadlock on a lock upgrade. One connection per file, shared by threads under a
lock.
"""

from __future__ import annotations

import sqlite3
import threading
from collections.abc import Iterator
from contextlib import contextmanager
from datetime import UTC, datetime
from pathlib import Path
from typing import ClassVar, Self

from gateway.errors import GatewayError


def iso(ts: datetime) -> str:
    """A time as stored in our tables' text columns: UTC with microseconds and a Z, so that text order is
    time order and `--since` compares strings."""
    ts = ts if ts.tzinfo else ts.replace(tzinfo=UTC)
    return ts.astimezone(UTC).strftime("%Y-%m-%dT%H:%M:%S.%fZ")


def parse_iso(text: str) -> datetime:
    """A stored time (`iso`) read back, aware, in UTC."""
    return datetime.strptime(text, "%Y-%m-%dT%H:%M:%S.%fZ").replace(tzinfo=UTC)


class SqliteFile:
    """Subclasses name the file (`noun`), its `schema` and `schema_version`, and the `error` they raise."""

    noun: ClassVar[str]  # "job queue": in messages as "the job queue is busy"
    schema: ClassVar[str]
    schema_version: ClassVar[int]
    error: ClassVar[type[GatewayError]]
    synchronous: ClassVar[str] = (
        "FULL"  # or "NORMAL": durable across a crash of the process, not of the power
    )

    def __init__(self, path: Path, *, busy_timeout: float = 10.0) -> None:
        self.path = Path(path)
        self.busy_timeout = busy_timeout
        self._db: sqlite3.Connection | None = None
        self._lock = threading.RLock()

    def open(self, *, create: bool = True) -> Self:
        if not create and not self.path.is_file():
            raise self.error(f"no {self.noun} at {self.path}")
        self.path.parent.mkdir(parents=True, exist_ok=True)
        db = sqlite3.connect(
            self.path, timeout=self.busy_timeout, isolation_level=None, check_same_thread=False
        )
        db.row_factory = sqlite3.Row
        try:
            db.execute("PRAGMA journal_mode=WAL")
            db.execute(f"PRAGMA synchronous={self.synchronous}")
            db.execute(f"PRAGMA busy_timeout={int(self.busy_timeout * 1000)}")
            version = db.execute("PRAGMA user_version").fetchone()[0]
            if version > self.schema_version:
                raise self.error(f"{self.path} was written by a newer cnc-gateway (schema {version})")
            if version < self.schema_version:  # a new file (later: migrations); else opening writes nothing
                db.executescript(self.schema)
                db.execute(f"PRAGMA user_version={self.schema_version}")
        except sqlite3.DatabaseError as exc:
            db.close()
            raise self.error(f"cannot use the {self.noun} {self.path}: {exc}") from None
        except BaseException:
            db.close()
            raise
        self._db = db
        return self

    def close(self) -> None:
        with self._lock:
            if self._db is not None:
                self._db.close()
                self._db = None

    def __enter__(self) -> Self:
        return self.open()

    def __exit__(self, *exc_info: object) -> None:
        self.close()

    @property
    def db(self) -> sqlite3.Connection:
        if self._db is None:
            raise self.error(f"the {self.noun} is not open")
        return self._db

    @contextmanager
    def _write(self) -> Iterator[sqlite3.Connection]:
        """One write transaction, taken at once (BEGIN IMMEDIATE) so it never deadlocks on upgrade."""
        with self._lock:
            db = self.db
            try:
                db.execute("BEGIN IMMEDIATE")
            except sqlite3.OperationalError as exc:
                raise self.error(f"the {self.noun} is busy: {exc}") from None
            try:
                yield db
            except BaseException:
                db.execute("ROLLBACK")
                raise
            db.execute("COMMIT")
