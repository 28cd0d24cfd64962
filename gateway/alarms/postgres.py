"""The alarm history in PostgreSQL (`alarm_history: postgresql://…` in the gateway file).

The same tables and transitions as the SQLite file (gateway/alarms/store.py), one database for every
shard of a fleet: `cnc-gateway alarms list -c gateway.yaml` and the console answer for the whole plant,
and a machine served by another shard after a restart finds its retained occurrences (acknowledged or
not) where the last one left them. Times are `timestamptz` in UTC. The schema is versioned as the job
queue's (`schema_versions`, component `alarm-history`).
"""

from __future__ import annotations

import json
from collections.abc import Sequence
from datetime import UTC, datetime
from typing import Any, Self

from gateway.alarms.history_filter import history_query
from gateway.alarms.records import ActiveAlarm, AlarmRecord, Kind
from gateway.errors import AlarmStoreError
from gateway.postgres import Database, Row

COMPONENT = "alarm-history"
MIGRATIONS = (
    """
    CREATE TABLE alarm_occurrences (
        occurrence BIGSERIAL PRIMARY KEY,
        machine TEXT NOT NULL,
        alarm_id TEXT NOT NULL,
        text TEXT NOT NULL,
        severity INTEGER NOT NULL,
        class INTEGER,
        parameters TEXT NOT NULL DEFAULT '{}',
        raised_at TIMESTAMPTZ NOT NULL,
        cleared_at TIMESTAMPTZ,
        acked_at TIMESTAMPTZ,
        acked_by TEXT NOT NULL DEFAULT '',
        ack_comment TEXT NOT NULL DEFAULT '',
        confirmed_at TIMESTAMPTZ,
        confirmed_by TEXT NOT NULL DEFAULT '',
        confirm_comment TEXT NOT NULL DEFAULT '',
        retained BOOLEAN NOT NULL DEFAULT TRUE
    );
    CREATE INDEX alarm_occurrences_machine_raised ON alarm_occurrences (machine, raised_at);
    CREATE INDEX alarm_occurrences_retained ON alarm_occurrences (machine, retained);
    CREATE TABLE alarm_transitions (
        id BIGSERIAL PRIMARY KEY,
        occurrence BIGINT NOT NULL REFERENCES alarm_occurrences (occurrence),
        kind TEXT NOT NULL,
        ts TIMESTAMPTZ NOT NULL,
        "user" TEXT NOT NULL DEFAULT '',
        comment TEXT NOT NULL DEFAULT ''
    );
    CREATE INDEX alarm_transitions_occurrence ON alarm_transitions (occurrence);
    """,
)


def _utc(ts: datetime | None) -> datetime | None:
    if ts is None:
        return None
    return (ts if ts.tzinfo else ts.replace(tzinfo=UTC)).astimezone(UTC)


def _record(row: Row) -> AlarmRecord:
    raised = _utc(row["raised_at"])
    assert raised is not None
    return AlarmRecord(
        occurrence=int(row["occurrence"]),
        machine=row["machine"],
        id=row["alarm_id"],
        text=row["text"],
        severity=row["severity"],
        severity_class=row["class"],
        raised_at=raised,
        parameters=json.loads(row["parameters"] or "{}"),
        cleared_at=_utc(row["cleared_at"]),
        acked_at=_utc(row["acked_at"]),
        acked_by=row["acked_by"],
        ack_comment=row["ack_comment"],
        confirmed_at=_utc(row["confirmed_at"]),
        confirmed_by=row["confirmed_by"],
        confirm_comment=row["confirm_comment"],
    )


class PostgresAlarmStore:
    """AlarmStore's methods on a PostgreSQL database: blocking, thread-safe, one transaction each."""

    def __init__(self, url: str) -> None:
        self.db = Database(url, noun="alarm history", error=AlarmStoreError)

    def open(self, *, create: bool = True) -> Self:
        """Connect, and bring the tables to this gateway's schema (both ways: the tables are shared)."""
        try:
            self.db.open()
            self.db.migrate(COMPONENT, MIGRATIONS)
        except BaseException:
            self.db.close()
            raise
        return self

    def close(self) -> None:
        self.db.close()

    def __enter__(self) -> Self:
        return self.open()

    def __exit__(self, *exc_info: object) -> None:
        self.close()

    def apply(
        self,
        machine: str,
        raised: Sequence[tuple[ActiveAlarm, int]],
        cleared: Sequence[tuple[int, datetime, bool]],
        ts: datetime,
    ) -> list[int]:
        """As AlarmStore.apply: one look at the controller's list in one transaction; the new numbers."""
        numbers: list[int] = []
        with self.db.transaction() as tx:
            for occurrence, when, retained in cleared:
                tx.execute(
                    "UPDATE alarm_occurrences SET cleared_at = %s, retained = %s"
                    " WHERE occurrence = %s AND cleared_at IS NULL",
                    (_utc(when), retained, occurrence),
                )
                tx.execute(
                    "INSERT INTO alarm_transitions (occurrence, kind, ts) VALUES (%s, %s, %s)",
                    (occurrence, Kind.CLEARED.value, _utc(when)),
                )
            for entry, severity in raised:
                number = int(
                    tx.scalar(
                        "INSERT INTO alarm_occurrences"
                        " (machine, alarm_id, text, severity, class, parameters, raised_at)"
                        " VALUES (%s, %s, %s, %s, %s, %s, %s) RETURNING occurrence",
                        (
                            machine,
                            entry.id,
                            entry.text,
                            severity,
                            entry.severity_class,
                            json.dumps(dict(entry.parameters), default=str),
                            _utc(ts),
                        ),
                    )
                )
                tx.execute(
                    "INSERT INTO alarm_transitions (occurrence, kind, ts) VALUES (%s, %s, %s)",
                    (number, Kind.RAISED.value, _utc(ts)),
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
        with self.db.transaction() as tx:
            done = tx.one(
                f"UPDATE alarm_occurrences SET {column}_at = %s, {by} = %s, {note} = %s, retained = %s"
                f" WHERE occurrence = %s AND {column}_at IS NULL RETURNING occurrence",
                (_utc(ts), user, comment, retained, occurrence),
            )
            if done is None:
                return False
            tx.execute(
                'INSERT INTO alarm_transitions (occurrence, kind, ts, "user", comment)'
                " VALUES (%s, %s, %s, %s, %s)",
                (occurrence, kind.value, _utc(ts), user, comment),
            )
        return True

    def retained(self, machine: str) -> list[AlarmRecord]:
        """The occurrences that still need attention, oldest first (what a start begins from)."""
        with self.db.transaction() as tx:
            rows = tx.all(
                "SELECT * FROM alarm_occurrences WHERE machine = %s AND retained ORDER BY occurrence",
                (machine,),
            )
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
            "alarm_occurrences",
            "%s",
            _utc,
            machine=machine,
            since=since,
            active_only=active_only,
            limit=limit,
        )
        with self.db.transaction() as tx:
            rows = tx.all(sql, params)
        return [_record(r) for r in rows]

    def transitions(self, occurrence: int) -> list[dict[str, Any]]:
        """One occurrence's transitions, in order: kind, ts, user, comment."""
        with self.db.transaction() as tx:
            rows = tx.all(
                'SELECT kind, ts, "user", comment FROM alarm_transitions WHERE occurrence = %s ORDER BY id',
                (occurrence,),
            )
        return [
            {"kind": r["kind"], "ts": _utc(r["ts"]), "user": r["user"], "comment": r["comment"]} for r in rows
        ]
