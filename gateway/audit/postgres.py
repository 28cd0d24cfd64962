"""The audit table in PostgreSQL (`audit: postgresql://…` in the gateway file): one trail for a fleet.

With shards, each process would otherwise keep its own `audit.sqlite3`, and "who changed this machine"
would be a question to every host that ever served it. Here every shard writes to one table, which
`cnc-gateway audit list -c gateway.yaml` and the console read. Same columns, same order and filters as
the SQLite table (gateway/audit/store.py), plus the process that recorded the entry (`recorded_by`:
its `CNC_SHARD`, else host and pid). Times are `timestamptz` (UTC: gateway/postgres.py sets the
session's zone). The schema is versioned as the job queue's (`schema_versions`, component
`audit-trail`): a newer gateway migrates, an older one refuses.
"""

from __future__ import annotations

import os
import socket
from collections.abc import Iterable
from datetime import UTC, datetime, timedelta

from gateway.audit.filter import audit_query
from gateway.audit.store import AuditRow
from gateway.errors import AuditStoreError
from gateway.model.audit import AuditEntry
from gateway.postgres import Database

COMPONENT = "audit-trail"
MIGRATIONS = (
    """
    CREATE TABLE audit (
        id BIGSERIAL PRIMARY KEY,
        ts TIMESTAMPTZ NOT NULL,
        kind TEXT NOT NULL,
        machine TEXT NOT NULL,
        target TEXT NOT NULL,
        origin TEXT NOT NULL,
        "user" TEXT,
        role TEXT,
        old TEXT,
        new TEXT,
        status TEXT NOT NULL,
        reason TEXT NOT NULL,
        duration_ms DOUBLE PRECISION NOT NULL,
        recorded_by TEXT NOT NULL
    );
    CREATE INDEX audit_ts ON audit (ts);
    CREATE INDEX audit_machine_ts ON audit (machine, ts);
    CREATE INDEX audit_user_ts ON audit ("user", ts);
    """,
)
COLUMNS = 'ts, kind, machine, target, origin, "user", role, old, new, status, reason, duration_ms'


def recorder() -> str:
    """Who records: the shard (`CNC_SHARD`, set by `cnc-gateway fleet`), else host and process."""
    shard = os.environ.get("CNC_SHARD")
    return f"shard {shard}" if shard else f"{socket.gethostname()}:{os.getpid()}"


class PostgresAuditStore:
    """The audit table in a PostgreSQL database: the methods of AuditStore, blocking, thread-safe."""

    def __init__(self, url: str, *, create: bool = True) -> None:
        self.db = Database(url, noun="audit table", error=AuditStoreError)
        self.recorded_by = recorder()
        try:
            self.db.open()
            self.db.migrate(COMPONENT, MIGRATIONS)  # create=False too: the table is the trail's, not ours
        except BaseException:
            self.db.close()
            raise

    def close(self) -> None:
        self.db.close()

    def insert(self, entries: Iterable[AuditEntry]) -> int:
        """One transaction for the whole batch."""
        rows = [
            (
                e.time if e.time.tzinfo else e.time.replace(tzinfo=UTC),
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
                self.recorded_by,
            )
            for e in entries
        ]
        if not rows:
            return 0
        values = ", ".join(["(%s, %s, %s, %s, %s, %s, %s, %s, %s, %s, %s, %s, %s)"] * len(rows))
        flat = [value for row in rows for value in row]
        with self.db.transaction() as tx:
            tx.execute(f"INSERT INTO audit ({COLUMNS}, recorded_by) VALUES {values}", flat)
        return len(rows)

    def prune(self, days: int, now: datetime | None = None) -> int:
        """Delete entries older than `days` days (0: keep everything). Returns how many went."""
        if days <= 0:
            return 0
        cutoff = (now or datetime.now(UTC)) - timedelta(days=days)
        with self.db.transaction() as tx:
            gone = tx.scalar(
                "WITH gone AS (DELETE FROM audit WHERE ts < %s RETURNING 1) SELECT count(*) FROM gone",
                (cutoff,),
            )
        return int(gone or 0)

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
        """Newest first, as AuditStore.query."""
        sql, params = audit_query(
            COLUMNS,
            "%s",
            lambda t: t,
            machine=machine,
            user=user,
            origin=origin,
            kind=kind,
            since=since,
            limit=limit,
        )
        with self.db.transaction() as tx:
            rows = tx.all(sql, params)
        return [
            AuditRow(
                int(r["id"]),
                AuditEntry(
                    r["ts"].astimezone(UTC), r["kind"], r["machine"], r["target"], r["origin"], r["user"],
                    r["role"], r["old"], r["new"], r["status"], r["reason"], float(r["duration_ms"]) / 1000.0,
                ),
            )
            for r in rows
        ]  # fmt: skip
