"""The audit trail's filtered read (`query`), written once for both of its tables.

The SQLite file (gateway/audit/store.py) and PostgreSQL (gateway/audit/postgres.py) hold the same entries,
with another placeholder (`?`, `%s`) and another form of a time (ISO text, timestamptz); which entries a
filter selects, and in what order, must not differ (`cnc-gateway audit list` and the console read either).
"""

from __future__ import annotations

from collections.abc import Callable
from datetime import datetime
from typing import Any


def audit_query(
    columns: str,
    mark: str,
    when: Callable[[datetime], Any],
    *,
    machine: str | None,
    user: str | None,
    origin: str | None,
    kind: str | None,
    since: datetime | None,
    limit: int,
) -> tuple[str, list[Any]]:
    """SQL and parameters for the entries newest first. `mark` is the table's placeholder, `when` turns a
    time into the table's form of it; `"user"` is quoted: a reserved word in PostgreSQL (SQLite takes it)."""
    where: list[str] = []
    params: list[Any] = []
    for column, value in (("machine", machine), ('"user"', user), ("origin", origin), ("kind", kind)):
        if value is not None:
            where.append(f"{column} = {mark}")
            params.append(value)
    if since is not None:
        where.append(f"ts >= {mark}")
        params.append(when(since))
    sql = f"SELECT id, {columns} FROM audit"  # the columns and the placeholder are constants, never input
    if where:
        sql += " WHERE " + " AND ".join(where)
    sql += f" ORDER BY ts DESC, id DESC LIMIT {mark}"
    params.append(max(1, limit))
    return sql, params
