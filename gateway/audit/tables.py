"""Where the audit trail is kept: the SQLite file in the state directory, or a PostgreSQL database.

The trail, the console and the CLI open it here by what the gateway file says (`audit:`), so that none
of them imports psycopg unless the table is in PostgreSQL.
"""

from __future__ import annotations

from collections.abc import Iterable
from datetime import datetime
from pathlib import Path
from typing import Protocol

from gateway.audit.store import AuditRow, AuditStore, audit_path
from gateway.model.audit import AuditEntry


class AuditTable(Protocol):
    """What the trail writes with and the readers read with (AuditStore, PostgresAuditStore)."""

    def insert(self, entries: Iterable[AuditEntry]) -> int: ...

    def prune(self, days: int, now: datetime | None = None) -> int: ...

    def query(
        self,
        *,
        machine: str | None = None,
        user: str | None = None,
        since: datetime | None = None,
        limit: int = 100,
        origin: str | None = None,
        kind: str | None = None,
    ) -> list[AuditRow]: ...

    def close(self) -> None: ...


def where_of(database: str | None, state_dir: Path) -> Path | str:
    """The gateway file's `audit:` URL, or the SQLite file in the state directory."""
    return database if database is not None else audit_path(state_dir)


def open_table(where: Path | str, *, create: bool = True) -> AuditTable:
    """The table at `where`: a PostgreSQL URL (str) or a SQLite file (Path). Raises AuditStoreError."""
    if isinstance(where, str):
        from gateway.audit.postgres import PostgresAuditStore

        return PostgresAuditStore(where, create=create)
    return AuditStore(where, create=create)


def describe(where: Path | str) -> str:
    """`where` as messages show it (a URL without its password)."""
    if isinstance(where, str):
        from gateway.postgres import redact

        return redact(where)
    return str(where)
