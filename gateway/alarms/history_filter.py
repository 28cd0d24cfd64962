"""The alarm history's filtered read (`history`), written once for both of its stores.

The SQLite file (gateway/alarms/store.py) and PostgreSQL (gateway/alarms/postgres.py) keep the same
occurrences under other table names, with another placeholder (`?`, `%s`) and another form of a time
(ISO text, timestamptz); which occurrences a filter selects, and in what order, must not differ.
"""

from __future__ import annotations

from collections.abc import Callable
from datetime import datetime
from typing import Any


def history_query(
    table: str,
    mark: str,
    when: Callable[[datetime], Any],
    *,
    machine: str | None,
    since: datetime | None,
    active_only: bool,
    limit: int,
) -> tuple[str, list[Any]]:
    """SQL and parameters: occurrences newest first, those raised since `since` and those still active then.

    `mark` is the store's placeholder, `when` turns a time into the store's form of it."""
    where: list[str] = []
    params: list[Any] = []
    if machine is not None:
        where.append(f"machine = {mark}")
        params.append(machine)
    if since is not None:
        where.append(f"(raised_at >= {mark} OR cleared_at IS NULL OR cleared_at >= {mark})")
        params += [when(since), when(since)]
    if active_only:
        where.append("cleared_at IS NULL")
    sql = f"SELECT * FROM {table}"  # the table and the placeholder are the stores' constants, never input
    if where:
        sql += " WHERE " + " AND ".join(where)
    sql += f" ORDER BY raised_at DESC, occurrence DESC LIMIT {mark}"
    params.append(limit)
    return sql, params
