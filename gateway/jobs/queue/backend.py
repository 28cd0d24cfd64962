"""Which store keeps the job queue: the gateway file's `queue:` (a PostgreSQL URL), or the SQLite file."""

from __future__ import annotations

import socket
from pathlib import Path

from gateway.jobs.queue.base import JobStore
from gateway.jobs.queue.store import JobQueue


def sqlite_path(state_dir: Path) -> Path:
    return state_dir / "jobs" / "queue.sqlite3"


def job_store(queue: str | None, state_dir: Path) -> JobStore:
    """The queue the gateway file names (not opened yet): PostgreSQL for `queue: postgresql://…`, else the
    SQLite file in the state directory (the embedded default). psycopg is imported only for the first."""
    if queue is not None:  # checked by the gateway file's model: a PostgreSQL URL
        from gateway.jobs.queue.postgres import PostgresJobQueue

        # Which intake received a job: this host's state directory (each shard has its own).
        return PostgresJobQueue(queue, received_by=f"{socket.gethostname()}:{state_dir.resolve()}")
    return JobQueue(sqlite_path(state_dir))
