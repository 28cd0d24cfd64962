"""The alarm history: one SQLite file (stdlib sqlite3, WAL) in the state directory.

Every occurrence is a row; every transition (raised, cleared, acknowledged,
confirmed) is a row in `transitions`, written in the same transaction as the
occurrence's new state. The gateway reloads the occurrences still `retained` at
start-up, so acknowledgements survive a restart, and `cnc-gateway alarms list`
reads the same file from another process while the gateway writes to it.

Methods are synchronous and thread-safe; the running gateway calls them from
one worker thread (gateway/alarms/service.py), never on the event loop.
"""

from __future__ import annotations

import json
import sqlite3
from collections.abc import Sequence
from datetime import datetime
from pathlib import Path
from typing import Any, Protocol, Self

from gateway.alarms.history_filter import history_query
from gateway.alarms.records import ActiveAlarm, AlarmRecord, Kind, iso, parse_iso
from gateway.errors import AlarmStoreError
from gateway.sqlite_file import SqliteFile

SCHEMA_VERSION = 1
FILE_NAME = "alarms.sqlite3"

_SCHEMA = """
CREATE TABLE IF NOT EXISTS occurrences (
    occurrence INTEGER PRIMARY KEY AUTOINCREMENT,
    machine TEXT NOT NULL,
    alarm_id TEXT NOT NULL,
    text TEXT NOT NULL,
    severity INTEGER NOT NULL,
    class INTEGER,
    parameters TEXT NOT NULL DEFAULT '{}',
    raised_at TEXT NOT NULL,
    cleared_at TEXT,
    acked_at TEXT,
    acked_by TEXT NOT NULL DEFAULT '',
    ack_comment TEXT NOT NULL DEFAULT '',
    confirmed_at TEXT,
    confirmed_by TEXT NOT NULL DEFAULT '',
    confirm_comment TEXT NOT NULL DEFAULT '',
    retained INTEGER NOT NULL DEFAULT 1
);
CREATE INDEX IF NOT EXISTS occurrences_machine_raised ON occurrences (machine, raised_at);
CREATE INDEX IF NOT EXISTS occurrences_retained ON occurrences (machine, retained);
CREATE TABLE IF NOT EXISTS transitions (
    id INTEGER PRIMARY KEY AUTOINCREMENT,
    occurrence INTEGER NOT NULL REFERENCES occurrences (occurrence),
    kind TEXT NOT NULL,
    ts TEXT NOT NULL,
    user TEXT NOT NULL DEFAULT '',
    comment TEXT NOT NULL DEFAULT ''
);
CREATE INDEX IF NOT EXISTS transitions_occurrence ON transitions (occurrence);
"""


def store_path(state_dir: Path) -> Path:
    return state_dir / FILE_NAME


class AlarmHistory(Protocol):
    """What the alarm managers and readers use: the SQLite file (AlarmStore) or PostgreSQL
    (gateway/alarms/postgres.py), by what the gateway file's `alarm_history:` says."""

    def open(self, *, create: bool = True) -> Self: ...

    def close(self) -> None: ...

    def apply(
        self,
        machine: str,
        raised: Sequence[tuple[ActiveAlarm, int]],
        cleared: Sequence[tuple[int, datetime, bool]],
        ts: datetime,
    ) -> list[int]: ...

    def acknowledge(self, occurrence: int, ts: datetime, user: str, comment: str, retained: bool) -> bool: ...

    def confirm(self, occurrence: int, ts: datetime, user: str, comment: str, retained: bool) -> bool: ...

    def retained(self, machine: str) -> list[AlarmRecord]: ...

    def history(
        self,
        machine: str | None = None,
        since: datetime | None = None,
        *,
        active_only: bool = False,
        limit: int = 1000,
    ) -> list[AlarmRecord]: ...

    def transitions(self, occurrence: int) -> list[dict[str, Any]]: ...


def history_at(database: str | None, state_dir: Path) -> AlarmHistory:
    """The gateway file's `alarm_history:` PostgreSQL database, else the SQLite file of the state
    directory; not yet opened. psycopg is imported only for the first."""
    if database is not None:
        from gateway.alarms.postgres import PostgresAlarmStore

        return PostgresAlarmStore(database)
    return AlarmStore(store_path(state_dir))


def _record(row: sqlite3.Row) -> AlarmRecord:
    raised = parse_iso(row["raised_at"])
    assert raised is not None
    return AlarmRecord(
        occurrence=row["occurrence"],
        machine=row["machine"],
        id=row["alarm_id"],
        text=row["text"],
        severity=row["severity"],
        severity_class=row["class"],
        raised_at=raised,
        parameters=json.loads(row["parameters"] or "{}"),
        cleared_at=parse_iso(row["cleared_at"]),
        acked_at=parse_iso(row["acked_at"]),
        acked_by=row["acked_by"],
        ack_comment=row["ack_comment"],
        confirmed_at=parse_iso(row["confirmed_at"]),
        confirmed_by=row["confirmed_by"],
        confirm_comment=row["confirm_comment"],
    )


class AlarmStore(SqliteFile):
    """The alarm file. `with AlarmStore(path) as store:` (or open()/close())."""

    noun = "alarm history"
    schema = _SCHEMA
    schema_version = SCHEMA_VERSION
    error = AlarmStoreError

    # --- transitions -----------------------------------------------------------------------------

    def apply(
        self,
        machine: str,
        raised: Sequence[tuple[ActiveAlarm, int]],
        cleared: Sequence[tuple[int, datetime, bool]],
        ts: datetime,
    ) -> list[int]:
        """One look at the controller's list, in one transaction: new occurrences (entry, severity), raised
        at `ts`, and cleared ones (occurrence, when, still retained). Returns the new occurrences' numbers."""
        stamp = iso(ts)
        numbers: list[int] = []
        with self._write() as db:
            for occurrence, when, retained in cleared:
                db.execute(
                    "UPDATE occurrences SET cleared_at = ?, retained = ?"
                    " WHERE occurrence = ? AND cleared_at IS NULL",
                    (iso(when), int(retained), occurrence),
                )
                db.execute(
                    "INSERT INTO transitions (occurrence, kind, ts) VALUES (?, ?, ?)",
                    (occurrence, Kind.CLEARED.value, iso(when)),
                )
            for entry, severity in raised:
                cur = db.execute(
                    "INSERT INTO occurrences"
                    " (machine, alarm_id, text, severity, class, parameters, raised_at)"
                    " VALUES (?, ?, ?, ?, ?, ?, ?)",
                    (
                        machine,
                        entry.id,
                        entry.text,
                        severity,
                        entry.severity_class,
                        json.dumps(dict(entry.parameters), default=str),
                        stamp,
                    ),
                )
                number = int(cur.lastrowid or 0)
                db.execute(
                    "INSERT INTO transitions (occurrence, kind, ts) VALUES (?, ?, ?)",
                    (number, Kind.RAISED.value, stamp),
                )
                numbers.append(number)
        return numbers

    def acknowledge(self, occurrence: int, ts: datetime, user: str, comment: str, retained: bool) -> bool:
        """Record an acknowledgement; False when it was already acknowledged (or is unknown)."""
        return self._mark(occurrence, "acked", Kind.ACKNOWLEDGED, ts, user, comment, retained)

    def confirm(self, occurrence: int, ts: datetime, user: str, comment: str, retained: bool) -> bool:
        return self._mark(occurrence, "confirmed", Kind.CONFIRMED, ts, user, comment, retained)

    def _mark(
        self, occurrence: int, column: str, kind: Kind, ts: datetime, user: str, comment: str, retained: bool
    ) -> bool:
        by, note = ("acked_by", "ack_comment") if column == "acked" else ("confirmed_by", "confirm_comment")
        stamp = iso(ts)
        with self._write() as db:
            cur = db.execute(
                f"UPDATE occurrences SET {column}_at = ?, {by} = ?, {note} = ?, retained = ? "
                f"WHERE occurrence = ? AND {column}_at IS NULL",
                (stamp, user, comment, int(retained), occurrence),
            )
            if cur.rowcount != 1:
                return False
            db.execute(
                "INSERT INTO transitions (occurrence, kind, ts, user, comment) VALUES (?, ?, ?, ?, ?)",
                (occurrence, kind.value, stamp, user, comment),
            )
        return True

    # --- queries ---------------------------------------------------------------------------------

    def retained(self, machine: str) -> list[AlarmRecord]:
        """The occurrences that still need attention, oldest first (what a restart starts from)."""
        with self._lock:
            rows = self.db.execute(
                "SELECT * FROM occurrences WHERE machine = ? AND retained = 1 ORDER BY occurrence", (machine,)
            ).fetchall()
        return [_record(r) for r in rows]

    def history(
        self,
        machine: str | None = None,
        since: datetime | None = None,
        *,
        active_only: bool = False,
        limit: int = 1000,
    ) -> list[AlarmRecord]:
        """Occurrences newest first: those raised since `since`, and those still active then."""
        sql, params = history_query(
            "occurrences", "?", iso, machine=machine, since=since, active_only=active_only, limit=limit
        )
        with self._lock:
            rows = self.db.execute(sql, params).fetchall()
        return [_record(r) for r in rows]

    def transitions(self, occurrence: int) -> list[dict[str, Any]]:
        """One occurrence's transitions, in order: kind, ts, user, comment."""
        with self._lock:
            rows = self.db.execute(
                "SELECT kind, ts, user, comment FROM transitions WHERE occurrence = ? ORDER BY id",
                (occurrence,),
            ).fetchall()
        return [
            {"kind": r["kind"], "ts": parse_iso(r["ts"]), "user": r["user"], "comment": r["comment"]}
            for r in rows
        ]
