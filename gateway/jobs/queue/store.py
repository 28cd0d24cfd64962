"""The durable job queue: one SQLite file (stdlib sqlite3, WAL) that nothing falls out of.

Every job is a row; every state change is a compare-and-set on the expected
state, recorded with its reason and time in a transitions table, in the same
transaction. So a gateway killed at any moment finds each job in exactly one
state, and the CLI (another process) can retry or cancel jobs while the gateway
runs: WAL lets readers and the one writer proceed together, a busy timeout
covers the brief write locks, and the running gateway notices other processes'
commits through `PRAGMA data_version` and picks them up by revision.

    RECEIVED -> VALIDATED -> QUEUED -> SENDING -> DELIVERED
         \\-> REJECTED    \\-> REJECTED  \\-> CANCELLED  \\-> QUEUED (retry later) | FAILED
    FAILED / CANCELLED -> QUEUED (retry from the CLI)

This is the embedded store; postgres.py keeps the same queue in PostgreSQL for shards
that share it (base.py: the JobStore both fit). Job ids (`J000042`) come from an
AUTOINCREMENT key, so they are stable across restarts and never reused. Methods are
synchronous and thread-safe; the async side calls them in a worker thread.
"""

from __future__ import annotations

import builtins
import json
import sqlite3
import time
from collections.abc import Iterator, Sequence
from pathlib import Path
from typing import Any, Literal

from gateway.errors import JobError
from gateway.jobs.queue.records import (
    ALLOWED,
    TERMINAL,
    Job,
    JobState,
    S,
    Transition,
    iso_utc,
    job_id,
    parse_job_id,
    parse_ts,
)
from gateway.shards.fence import Fence
from gateway.sqlite_file import SqliteFile

__all__ = ["ALLOWED", "TERMINAL", "Job", "JobQueue", "JobState", "Transition", "job_id", "parse_job_id"]

SCHEMA_VERSION = 1


_SCHEMA = """
CREATE TABLE IF NOT EXISTS jobs (
    seq INTEGER PRIMARY KEY AUTOINCREMENT,
    machine TEXT NOT NULL,
    filename TEXT NOT NULL,
    user TEXT NOT NULL DEFAULT '',
    origin TEXT NOT NULL DEFAULT '',
    size INTEGER NOT NULL,
    sha256 TEXT NOT NULL,
    priority INTEGER NOT NULL DEFAULT 0,
    state TEXT NOT NULL,
    reason TEXT NOT NULL DEFAULT '',
    attempts INTEGER NOT NULL DEFAULT 0,
    next_attempt_at REAL,
    received_at TEXT NOT NULL,
    updated_at TEXT NOT NULL,
    program_name TEXT,
    program_size INTEGER,
    program_sha256 TEXT,
    estimate TEXT,
    warnings TEXT NOT NULL DEFAULT '[]',
    delivered_name TEXT,
    delivered_at TEXT,
    rev INTEGER NOT NULL
);
CREATE INDEX IF NOT EXISTS jobs_machine_state ON jobs (machine, state, priority, seq);
CREATE INDEX IF NOT EXISTS jobs_rev ON jobs (rev);
CREATE INDEX IF NOT EXISTS jobs_sha ON jobs (machine, sha256);
CREATE TABLE IF NOT EXISTS transitions (
    id INTEGER PRIMARY KEY AUTOINCREMENT,
    seq INTEGER NOT NULL REFERENCES jobs (seq),
    state TEXT NOT NULL,
    previous TEXT,
    reason TEXT NOT NULL DEFAULT '',
    ts TEXT NOT NULL
);
CREATE INDEX IF NOT EXISTS transitions_seq ON transitions (seq);
CREATE TABLE IF NOT EXISTS meta (key TEXT PRIMARY KEY, value INTEGER NOT NULL);
INSERT OR IGNORE INTO meta (key, value) VALUES ('rev', 0);
"""


def _job(row: sqlite3.Row) -> Job:
    return Job(
        seq=row["seq"],
        machine=row["machine"],
        filename=row["filename"],
        user=row["user"],
        origin=row["origin"],
        size=row["size"],
        sha256=row["sha256"],
        priority=row["priority"],
        state=JobState(row["state"]),
        reason=row["reason"],
        attempts=row["attempts"],
        next_attempt_at=row["next_attempt_at"],
        received_at=parse_ts(row["received_at"]),  # type: ignore[arg-type]
        updated_at=parse_ts(row["updated_at"]),  # type: ignore[arg-type]
        program_name=row["program_name"],
        program_size=row["program_size"],
        program_sha256=row["program_sha256"],
        estimate=json.loads(row["estimate"]) if row["estimate"] else None,
        warnings=tuple(json.loads(row["warnings"] or "[]")),
        delivered_name=row["delivered_name"],
        delivered_at=parse_ts(row["delivered_at"]),
        rev=row["rev"],
    )


class JobQueue(SqliteFile):
    """The queue file. Open it with `with JobQueue(path) as q:` (or open()/close())."""

    noun = "job queue"
    shares_programs = False  # one process's queue: its spool keeps the programs
    schema = _SCHEMA
    schema_version = SCHEMA_VERSION
    error = JobError

    def __init__(self, path: Path, *, busy_timeout: float = 10.0, clock: Any = time.time) -> None:
        super().__init__(path, busy_timeout=busy_timeout)
        self.clock = clock

    def _next_rev(self, db: sqlite3.Connection) -> int:
        db.execute("UPDATE meta SET value = value + 1 WHERE key = 'rev'")
        return int(db.execute("SELECT value FROM meta WHERE key = 'rev'").fetchone()[0])

    def _get(self, db: sqlite3.Connection, seq: int) -> Job:
        row = db.execute("SELECT * FROM jobs WHERE seq = ?", (seq,)).fetchone()
        if row is None:
            raise JobError(f"no job {job_id(seq)}")
        return _job(row)

    def _move(
        self,
        db: sqlite3.Connection,
        seq: int,
        to: JobState,
        reason: str,
        *,
        expect: Sequence[JobState] | None = None,
        **columns: Any,
    ) -> Job:
        """Compare-and-set one job's state, with its transition row and a new revision."""
        job = self._get(db, seq)
        allowed_from = (
            expect if expect is not None else [s for s, targets in ALLOWED.items() if to in targets]
        )
        if job.state not in allowed_from or to not in ALLOWED[job.state]:
            raise JobError(f"{job.id} is {job.state}, so it cannot become {to}")
        now = self.clock()
        rev = self._next_rev(db)
        sets = {"state": to.value, "reason": reason, "updated_at": iso_utc(now), "rev": rev, **columns}
        assignments = ", ".join(f"{k} = ?" for k in sets)
        db.execute(f"UPDATE jobs SET {assignments} WHERE seq = ?", (*sets.values(), seq))
        db.execute(
            "INSERT INTO transitions (seq, state, previous, reason, ts) VALUES (?, ?, ?, ?, ?)",
            (seq, to.value, job.state.value, reason, iso_utc(now)),
        )
        return self._get(db, seq)

    # --- the pipeline ------------------------------------------------------------------------------

    def receive(
        self,
        machine: str,
        filename: str,
        size: int,
        sha256: str,
        *,
        user: str = "",
        origin: str = "",
        priority: int = 0,
    ) -> Job:
        """A complete upload: a new job in RECEIVED."""
        with self._write() as db:
            now = iso_utc(self.clock())
            rev = self._next_rev(db)
            cur = db.execute(
                "INSERT INTO jobs (machine, filename, user, origin, size, sha256, priority, state, reason,"
                " received_at, updated_at, rev) VALUES (?, ?, ?, ?, ?, ?, ?, 'RECEIVED', '', ?, ?, ?)",
                (machine, filename, user, origin, size, sha256, priority, now, now, rev),
            )
            seq = int(cur.lastrowid or 0)
            db.execute(
                "INSERT INTO transitions (seq, state, previous, reason, ts)"
                " VALUES (?, 'RECEIVED', NULL, ?, ?)",
                (seq, f"from {user or 'unknown'} via {origin or 'unknown'}", now),
            )
            return self._get(db, seq)

    def reject(self, seq: int, reason: str) -> Job:
        with self._write() as db:
            return self._move(db, seq, S.REJECTED, reason, expect=(S.RECEIVED, S.VALIDATED))

    def accept(
        self,
        seq: int,
        *,
        duplicates: Literal["skip", "replace"],
        program_size: int,
        program_sha256: str,
        program_name: str | None = None,
        estimate: dict[str, Any] | None = None,
        warnings: Sequence[str] = (),
        reason: str = "",
        program: Path | None = None,
    ) -> tuple[Job, list[Job]]:
        """Validation passed: VALIDATED, then QUEUED, or REJECTED as a duplicate, in one transaction.

        Returns the job and the earlier jobs it replaced (now CANCELLED). `program` is not stored: the
        SQLite queue belongs to one process, whose spool keeps the program.
        """
        replaced: list[Job] = []
        with self._write() as db:
            job = self._move(
                db,
                seq,
                S.VALIDATED,
                reason,
                expect=(S.RECEIVED,),
                program_size=program_size,
                program_sha256=program_sha256,
                program_name=program_name,
                estimate=json.dumps(estimate) if estimate is not None else None,
                warnings=json.dumps(list(warnings)),
            )
            earlier = [
                _job(row)
                for row in db.execute(
                    "SELECT * FROM jobs WHERE machine = ? AND sha256 = ? AND seq != ?"
                    " AND state IN ('QUEUED', 'SENDING') ORDER BY seq",
                    (job.machine, job.sha256, seq),
                )
            ]
            if earlier and (duplicates == "skip" or any(e.state is S.SENDING for e in earlier)):
                first = earlier[0]
                reason = f"duplicate of {first.id} ({first.filename}), which is {first.state.value.lower()}"
                return self._move(db, seq, S.REJECTED, reason, expect=(S.VALIDATED,)), []
            for old in earlier:
                replaced.append(
                    self._move(db, old.seq, S.CANCELLED, f"replaced by {job.id}", expect=(S.QUEUED,))
                )
            return self._move(db, seq, S.QUEUED, "", expect=(S.VALIDATED,), next_attempt_at=None), replaced

    def program_chunks(self, seq: int) -> Iterator[bytes]:
        """The SQLite queue keeps no programs (the spool does): JobError."""
        raise JobError(f"{job_id(seq)}: the job queue {self.path} keeps no programs; they wait in the spool")

    def received_here(self, serves: Sequence[str] = (), limit: int = 10_000) -> list[Job]:
        """Jobs still RECEIVED: all of them (one process takes uploads into a SQLite queue)."""
        return self.list(states=(S.RECEIVED,), limit=limit, newest_first=False)

    def head(self, machine: str) -> Job | None:
        """The job a machine's worker handles next: SENDING (after a crash) first, then by priority, FIFO."""
        with self._lock:
            row = self.db.execute(
                "SELECT * FROM jobs WHERE machine = ? AND state IN ('SENDING', 'QUEUED')"
                " ORDER BY state = 'SENDING' DESC, priority DESC, seq LIMIT 1",
                (machine,),
            ).fetchone()
            return _job(row) if row else None

    def start_sending(self, seq: int, reason: str = "", *, fence: Fence | None = None) -> Job:
        """QUEUED -> SENDING, counting the attempt. JobError if someone (the CLI) changed it meanwhile."""
        _no_fence(fence)
        with self._write() as db:
            job = self._get(db, seq)
            return self._move(db, seq, S.SENDING, reason, expect=(S.QUEUED,), attempts=job.attempts + 1)

    def delivered(self, seq: int, name: str, reason: str = "", *, fence: Fence | None = None) -> Job:
        _no_fence(fence)
        with self._write() as db:
            return self._move(
                db,
                seq,
                S.DELIVERED,
                reason,
                expect=(S.SENDING,),
                delivered_name=name,
                delivered_at=iso_utc(self.clock()),
                next_attempt_at=None,
            )

    def send_failed(
        self, seq: int, reason: str, *, retry_at: float | None, fence: Fence | None = None
    ) -> Job:
        """A failed attempt: back to QUEUED until `retry_at`, or FAILED (dead letter) when None."""
        _no_fence(fence)
        with self._write() as db:
            if retry_at is None:
                return self._move(db, seq, S.FAILED, reason, expect=(S.SENDING,), next_attempt_at=None)
            return self._move(db, seq, S.QUEUED, reason, expect=(S.SENDING,), next_attempt_at=retry_at)

    def note(self, seq: int, reason: str) -> Job:
        """Change a job's reason without changing its state (auto-start outcome, progress notes)."""
        with self._write() as db:
            rev = self._next_rev(db)
            db.execute(
                "UPDATE jobs SET reason = ?, rev = ?, updated_at = ? WHERE seq = ?",
                (reason, rev, iso_utc(self.clock()), seq),
            )
            return self._get(db, seq)

    # --- operator actions (CLI) --------------------------------------------------------------------

    def retry(self, seq: int, by: str = "") -> Job:
        """A FAILED or CANCELLED job goes back to the queue with a fresh set of attempts."""
        with self._write() as db:
            job = self._get(db, seq)
            if job.state not in (S.FAILED, S.CANCELLED):
                raise JobError(f"{job.id} is {job.state}; only FAILED or CANCELLED jobs can be retried")
            reason = f"retry requested{' by ' + by if by else ''}"
            return self._move(
                db, seq, S.QUEUED, reason, expect=(S.FAILED, S.CANCELLED), attempts=0, next_attempt_at=None
            )

    def cancel(self, seq: int, by: str = "") -> Job:
        with self._write() as db:
            job = self._get(db, seq)
            if job.state is S.SENDING:
                raise JobError(
                    f"{job.id} is being sent right now; delete the program on the controller afterwards"
                )
            if job.state in TERMINAL:
                raise JobError(f"{job.id} is already {job.state}")
            reason = f"cancelled{' by ' + by if by else ''}"
            return self._move(db, seq, S.CANCELLED, reason, expect=(S.RECEIVED, S.VALIDATED, S.QUEUED))

    def set_priority(self, seq: int, priority: int) -> Job:
        with self._write() as db:
            job = self._get(db, seq)
            if job.state in TERMINAL or job.state is S.SENDING:
                raise JobError(f"{job.id} is {job.state}; only waiting jobs can change priority")
            rev = self._next_rev(db)
            db.execute("UPDATE jobs SET priority = ?, rev = ? WHERE seq = ?", (priority, rev, seq))
            return self._get(db, seq)

    # --- reading --------------------------------------------------------------------------------

    def get(self, seq: int) -> Job:
        with self._lock:
            return self._get(self.db, seq)

    # Below this method, `list` in annotations would name it: they say builtins.list.
    def list(
        self,
        *,
        machine: str | None = None,
        states: Sequence[JobState] = (),
        limit: int = 50,
        newest_first: bool = True,
    ) -> builtins.list[Job]:
        where, args = self._filter(machine, states)
        order = "DESC" if newest_first else "ASC"
        with self._lock:
            rows = self.db.execute(f"SELECT * FROM jobs{where} ORDER BY seq {order} LIMIT ?", (*args, limit))
            return [_job(r) for r in rows]

    def count(self, *, machine: str | None = None, states: Sequence[JobState] = ()) -> int:
        where, args = self._filter(machine, states)
        with self._lock:
            return int(self.db.execute(f"SELECT COUNT(*) FROM jobs{where}", args).fetchone()[0])

    def latest(self, machine: str, state: JobState) -> Job | None:
        with self._lock:
            row = self.db.execute(
                "SELECT * FROM jobs WHERE machine = ? AND state = ?"
                " ORDER BY updated_at DESC, seq DESC LIMIT 1",
                (machine, state.value),
            ).fetchone()
            return _job(row) if row else None

    def history(self, seq: int) -> builtins.list[Transition]:
        with self._lock:
            rows = self.db.execute(
                "SELECT t.*, j.machine FROM transitions t JOIN jobs j ON j.seq = t.seq"
                " WHERE t.seq = ? ORDER BY t.id",
                (seq,),
            )
            return [_transition(r) for r in rows]

    def changes_since(self, rev: int) -> builtins.list[Job]:
        """Jobs changed after revision `rev` (by this process or another), oldest change first."""
        with self._lock:
            rows = self.db.execute("SELECT * FROM jobs WHERE rev > ? ORDER BY rev", (rev,))
            return [_job(r) for r in rows]

    def transitions_since(self, last_id: int) -> builtins.list[Transition]:
        with self._lock:
            rows = self.db.execute(
                "SELECT t.*, j.machine FROM transitions t JOIN jobs j ON j.seq = t.seq"
                " WHERE t.id > ? ORDER BY t.id",
                (last_id,),
            )
            return [_transition(r) for r in rows]

    def marks(self) -> tuple[int, int]:
        """(latest revision, latest transition id): where a reader starts following changes."""
        with self._lock:
            rev = int(self.db.execute("SELECT value FROM meta WHERE key = 'rev'").fetchone()[0])
            row = self.db.execute("SELECT MAX(id) FROM transitions").fetchone()
            return rev, int(row[0] or 0)

    def data_version(self) -> int:
        """Changes when another connection commits: a cheap 'did the CLI touch the queue?' check."""
        with self._lock:
            return int(self.db.execute("PRAGMA data_version").fetchone()[0])

    @staticmethod
    def _filter(machine: str | None, states: Sequence[JobState]) -> tuple[str, tuple[Any, ...]]:
        clauses: builtins.list[str] = []
        args: builtins.list[Any] = []
        if machine is not None:
            clauses.append("machine = ?")
            args.append(machine)
        if states:
            clauses.append(f"state IN ({', '.join('?' for _ in states)})")
            args.extend(s.value for s in states)
        return (" WHERE " + " AND ".join(clauses) if clauses else ""), tuple(args)


def _no_fence(fence: Fence | None) -> None:
    if fence is not None:
        raise JobError(f"a SQLite job queue holds no leases, so it cannot check the fencing token {fence}")


def _transition(row: sqlite3.Row) -> Transition:
    return Transition(
        id=row["id"],
        seq=row["seq"],
        machine=row["machine"],
        state=JobState(row["state"]),
        previous=JobState(row["previous"]) if row["previous"] else None,
        reason=row["reason"],
        ts=parse_ts(row["ts"]),  # type: ignore[arg-type]
    )
