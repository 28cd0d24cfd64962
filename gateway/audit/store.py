"""The audit table: one SQLite file in the state directory, written by the trail, read by the CLI.

Times are stored as ISO-8601 UTC text with microseconds (`2026-05-06T07:08:09.123456Z`),
which sorts like the times themselves. Opened through `SqliteFile`: WAL mode lets
`cnc-gateway audit list` read while the gateway writes; synchronous=NORMAL, since
the log has every entry as well.
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass
from datetime import UTC, datetime, timedelta
from pathlib import Path

from gateway.audit.filter import audit_query
from gateway.errors import AuditStoreError
from gateway.model.audit import AuditEntry
from gateway.sqlite_file import SqliteFile, iso, parse_iso

FILE_NAME = "audit.sqlite3"
SCHEMA_VERSION = 1  # files from before the version was kept have 0, and the same table

SCHEMA = """
CREATE TABLE IF NOT EXISTS audit (
    id INTEGER PRIMARY KEY,
    ts TEXT NOT NULL,
    kind TEXT NOT NULL,
    machine TEXT NOT NULL,
    target TEXT NOT NULL,
    origin TEXT NOT NULL,
    user TEXT,
    role TEXT,
    old TEXT,
    new TEXT,
    status TEXT NOT NULL,
    reason TEXT NOT NULL,
    duration_ms REAL NOT NULL
);
CREATE INDEX IF NOT EXISTS audit_ts ON audit (ts);
CREATE INDEX IF NOT EXISTS audit_machine_ts ON audit (machine, ts);
CREATE INDEX IF NOT EXISTS audit_user_ts ON audit (user, ts);
"""

COLUMNS = "ts, kind, machine, target, origin, user, role, old, new, status, reason, duration_ms"


def audit_path(state_dir: Path) -> Path:
    return state_dir / FILE_NAME


@dataclass(frozen=True, slots=True)
class AuditRow:
    """An entry read back, with its row id."""

    id: int
    entry: AuditEntry


class AuditStore(SqliteFile):
    """Blocking SQLite access, open once made: the trail uses it from its own thread, the CLI directly."""

    noun = "audit table"
    schema = SCHEMA
    schema_version = SCHEMA_VERSION
    synchronous = "NORMAL"
    error = AuditStoreError

    def __init__(self, path: Path, *, create: bool = True) -> None:
        super().__init__(path)
        self.open(create=create)

    def insert(self, entries: Iterable[AuditEntry]) -> int:
        """One transaction for the whole batch."""
        rows = [
            (
                iso(e.time),
                e.kind,
                e.machine,
                e.target,
                e.origin,
                e.user,
                e.role,
                e.old,
                e.new,
                e.status,
                e.reason,
                round(e.duration * 1000.0, 3),
            )
            for e in entries
        ]
        if not rows:
            return 0
        with self._write() as db:
            db.executemany(f"INSERT INTO audit ({COLUMNS}) VALUES (?,?,?,?,?,?,?,?,?,?,?,?)", rows)
        return len(rows)

    def prune(self, days: int, now: datetime | None = None) -> int:
        """Delete entries older than `days` days (0: keep everything). Returns how many went."""
        if days <= 0:
            return 0
        cutoff = (now or datetime.now(UTC)) - timedelta(days=days)
        with self._write() as db:
            cur = db.execute("DELETE FROM audit WHERE ts < ?", (iso(cutoff),))
        return cur.rowcount

    def query(
        self,
        *,
        machine: str | None = None,
        user: str | None = None,
        since: datetime | None = None,
        limit: int = 100,
        origin: str | None = None,
        kind: str | None = None,
    ) -> list[AuditRow]:
        """Newest first."""
        sql, params = audit_query(
            COLUMNS, "?", iso, machine=machine, user=user, origin=origin, kind=kind, since=since, limit=limit
        )
        out = []
        with self._lock:
            rows = self.db.execute(sql, params).fetchall()
        for row in rows:
            (rowid, ts, kind, mach, target, origin, usr, role, old, new, status, reason, ms) = row
            entry = AuditEntry(
                parse_iso(ts), kind, mach, target, origin, usr, role, old, new, status, reason, ms / 1000.0
            )
            out.append(AuditRow(rowid, entry))
        return out
