"""The job queue in PostgreSQL, for gateway processes (shards) that share one queue (`queue: postgresql://…`).

The same queue as store.py's SQLite file: the same states and transitions (records.py),
each change a compare-and-set with its transition row and a new revision in one
transaction, readers following changes by revision. What differs is that many processes
write it at once, so:

- Every write transaction first locks the queue's revision row (`meta`, FOR UPDATE). Writes
  are thus serialised across processes: revisions and transition ids are handed out in
  commit order (so `changes_since`/`transitions_since` never skip a change that commits
  late), and two writers never deadlock on each other's rows. A job is then locked
  (FOR UPDATE) and compare-and-set on its state: of two processes that try to start sending
  the same job, one gets SENDING and the other a JobError, as with the SQLite file.
- A claim (`start_sending`) or its outcome (`delivered`, `send_failed`) may carry a fencing token
  (gateway/shards/fence.py); it is checked in the same transaction against the machine's
  lease (gateway/shards/leases.py), so a process that lost its lease cannot claim.
- Times are the database's TIMESTAMPTZ; `data_version` is the revision (it also moves with
  this process's own writes, which only wakes the watcher once more).
- Database errors are JobStoreError (a StoreError and a JobError), through gateway/postgres.py.

The queue also carries each accepted job's program (schema 2, `job_programs`), so that the shard
that serves a machine can deliver a job another shard's inbox took in (docs/scaling.md). The bytes
go in as rows of PROGRAM_CHUNK bytes (bytea), in the transaction that queues the job, and come back
a chunk at a time: a 50 MB program is never whole in memory. Chunked rows rather than large
objects: they are ordinary rows (deleted with a DELETE in the transaction that delivers the job,
never orphaned in pg_largeobject, dumped with the table, no large-object privileges to grant), and
psycopg has no large-object API, so large objects would be read by offset through lo_get anyway.
The chunks are written before the revision row is locked: the other writers (claims on every
shard) do not wait while a large program goes in.
"""

from __future__ import annotations

import builtins
import hashlib
import json
import time
from collections.abc import Iterator, Sequence
from contextlib import contextmanager
from datetime import UTC, datetime
from pathlib import Path
from typing import Any, Literal, Self

from gateway.errors import JobError, JobStoreError, StaleFence
from gateway.jobs.queue.records import ALLOWED, TERMINAL, Job, JobState, S, Transition, job_id
from gateway.postgres import Database, Row, Transaction
from gateway.shards.fence import Fence
from gateway.shards.leases import check_fence

COMPONENT = "job-queue"
MIGRATIONS = (
    # 1: the queue as store.py's schema 1 has it
    """
    CREATE TABLE jobs (
        seq BIGINT GENERATED ALWAYS AS IDENTITY PRIMARY KEY,
        machine TEXT NOT NULL,
        filename TEXT NOT NULL,
        "user" TEXT NOT NULL DEFAULT '',
        origin TEXT NOT NULL DEFAULT '',
        size BIGINT NOT NULL,
        sha256 TEXT NOT NULL,
        priority INTEGER NOT NULL DEFAULT 0,
        state TEXT NOT NULL,
        reason TEXT NOT NULL DEFAULT '',
        attempts INTEGER NOT NULL DEFAULT 0,
        next_attempt_at DOUBLE PRECISION,
        received_at TIMESTAMPTZ NOT NULL,
        updated_at TIMESTAMPTZ NOT NULL,
        program_name TEXT,
        program_size BIGINT,
        program_sha256 TEXT,
        estimate TEXT,
        warnings TEXT NOT NULL DEFAULT '[]',
        delivered_name TEXT,
        delivered_at TIMESTAMPTZ,
        rev BIGINT NOT NULL
    );
    CREATE INDEX jobs_machine_state ON jobs (machine, state, priority, seq);
    CREATE INDEX jobs_rev ON jobs (rev);
    CREATE INDEX jobs_sha ON jobs (machine, sha256);
    CREATE TABLE transitions (
        id BIGINT GENERATED ALWAYS AS IDENTITY PRIMARY KEY,
        seq BIGINT NOT NULL REFERENCES jobs (seq),
        state TEXT NOT NULL,
        previous TEXT,
        reason TEXT NOT NULL DEFAULT '',
        ts TIMESTAMPTZ NOT NULL
    );
    CREATE INDEX transitions_seq ON transitions (seq);
    CREATE TABLE meta (key TEXT PRIMARY KEY, value BIGINT NOT NULL);
    INSERT INTO meta (key, value) VALUES ('rev', 0);
    """,
    # 2: programs where every shard reads them; which process's intake received each job
    """
    CREATE TABLE job_programs (
        seq BIGINT NOT NULL,
        part INTEGER NOT NULL,
        data BYTEA NOT NULL,
        PRIMARY KEY (seq, part)
    );
    ALTER TABLE jobs ADD COLUMN received_by TEXT NOT NULL DEFAULT '';
    """,
)
PROGRAM_CHUNK = 1024 * 1024  # bytes per job_programs row: what is in memory at once, either way

_COLUMNS = frozenset(Job.__slots__) - {"seq", "rev"}  # what _move may set


def _job(row: Row) -> Job:
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
        received_at=row["received_at"],
        updated_at=row["updated_at"],
        program_name=row["program_name"],
        program_size=row["program_size"],
        program_sha256=row["program_sha256"],
        estimate=json.loads(row["estimate"]) if row["estimate"] else None,
        warnings=tuple(json.loads(row["warnings"] or "[]")),
        delivered_name=row["delivered_name"],
        delivered_at=row["delivered_at"],
        rev=row["rev"],
    )


def _transition(row: Row) -> Transition:
    return Transition(
        id=row["id"],
        seq=row["seq"],
        machine=row["machine"],
        state=JobState(row["state"]),
        previous=JobState(row["previous"]) if row["previous"] else None,
        reason=row["reason"],
        ts=row["ts"],
    )


class PostgresJobQueue:
    """The queue in a PostgreSQL database: `with PostgresJobQueue(url) as q:` (or open()/close()).

    `received_by` names this process's intake (its host and state directory) on the jobs it receives,
    so that after a restart it resumes its own uploads and leaves other shards' alone."""

    shares_programs = True  # the queue carries the programs: any shard can deliver any job

    def __init__(self, url: str, *, clock: Any = time.time, received_by: str = "") -> None:
        self.db = Database(url, noun="job queue", error=JobStoreError)
        self.clock = clock
        self.received_by = received_by

    def __str__(self) -> str:
        return str(self.db)

    def open(self) -> Self:
        self.db.open()
        self.db.migrate(COMPONENT, MIGRATIONS)
        return self

    def close(self) -> None:
        self.db.close()

    def __enter__(self) -> Self:
        return self.open()

    def __exit__(self, *exc_info: object) -> None:
        self.close()

    # --- inside a transaction ----------------------------------------------------------------------

    def _now(self) -> datetime:
        return datetime.fromtimestamp(self.clock(), UTC)

    @contextmanager
    def _write(self) -> Iterator[Transaction]:
        """One write transaction, the queue's revision row locked first (see the module's docstring)."""
        with self.db.transaction() as tx:
            self._lock_revision(tx)
            yield tx

    @staticmethod
    def _lock_revision(tx: Transaction) -> None:
        tx.execute("SELECT value FROM meta WHERE key = 'rev' FOR UPDATE")

    @staticmethod
    def _next_rev(tx: Transaction) -> int:
        return int(tx.scalar("UPDATE meta SET value = value + 1 WHERE key = 'rev' RETURNING value"))

    @staticmethod
    def _get(tx: Transaction, seq: int, *, lock: bool = False) -> Job:
        row = tx.one("SELECT * FROM jobs WHERE seq = %s" + (" FOR UPDATE" if lock else ""), (seq,))
        if row is None:
            raise JobError(f"no job {job_id(seq)}")
        return _job(row)

    def _move(
        self,
        tx: Transaction,
        seq: int,
        to: JobState,
        reason: str,
        *,
        expect: Sequence[JobState] | None = None,
        **columns: Any,
    ) -> Job:
        """Compare-and-set one job's state, with its transition row and a new revision."""
        job = self._get(tx, seq, lock=True)
        allowed_from = (
            expect if expect is not None else [s for s, targets in ALLOWED.items() if to in targets]
        )
        if job.state not in allowed_from or to not in ALLOWED[job.state]:
            raise JobError(f"{job.id} is {job.state}, so it cannot become {to}")
        unknown = set(columns) - _COLUMNS
        if unknown:  # the column names below are ours, never input; this keeps them so
            raise JobError(f"no such job columns: {sorted(unknown)}")
        now = self._now()
        rev = self._next_rev(tx)
        sets = {"state": to.value, "reason": reason, "updated_at": now, "rev": rev, **columns}
        assignments = ", ".join(f"{k} = %s" for k in sets)
        tx.execute(f"UPDATE jobs SET {assignments} WHERE seq = %s", (*sets.values(), seq))
        tx.execute(
            "INSERT INTO transitions (seq, state, previous, reason, ts) VALUES (%s, %s, %s, %s, %s)",
            (seq, to.value, job.state.value, reason, now),
        )
        return self._get(tx, seq)

    @staticmethod
    def _fenced(tx: Transaction, fence: Fence | None, job: Job, what: str) -> None:
        if fence is None:
            return
        if fence.machine != job.machine:
            raise JobError(
                f"{job.id} is for {job.machine}, not {fence.machine}: the fence {fence} cannot {what} it"
            )
        try:
            check_fence(tx, fence)
        except StaleFence as exc:
            raise JobError(f"{job.id} refused to {what}: {exc}") from None

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
        with self._write() as tx:
            now = self._now()
            rev = self._next_rev(tx)
            seq = int(
                tx.scalar(
                    'INSERT INTO jobs (machine, filename, "user", origin, size, sha256, priority, state,'
                    " reason, received_at, updated_at, rev, received_by)"
                    " VALUES (%s, %s, %s, %s, %s, %s, %s, 'RECEIVED', '', %s, %s, %s, %s)"
                    " RETURNING seq",
                    (
                        machine,
                        filename,
                        user,
                        origin,
                        size,
                        sha256,
                        priority,
                        now,
                        now,
                        rev,
                        self.received_by,
                    ),
                )
            )
            tx.execute(
                "INSERT INTO transitions (seq, state, previous, reason, ts)"
                " VALUES (%s, 'RECEIVED', NULL, %s, %s)",
                (seq, f"from {user or 'unknown'} via {origin or 'unknown'}", now),
            )
            return self._get(tx, seq)

    def reject(self, seq: int, reason: str) -> Job:
        with self._write() as tx:
            return self._move(tx, seq, S.REJECTED, reason, expect=(S.RECEIVED, S.VALIDATED))

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
    ) -> tuple[Job, builtins.list[Job]]:
        """Validation passed: VALIDATED, then QUEUED, or REJECTED as a duplicate, in one transaction, with
        the validated `program` (a file: its bytes, checked against `program_sha256`) stored with the job."""
        replaced: builtins.list[Job] = []
        with self.db.transaction() as tx:
            if program is not None:  # before the revision lock: see the module's docstring
                self._store_program(tx, seq, program, program_size, program_sha256)
            self._lock_revision(tx)
            job = self._move(
                tx,
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
                for row in tx.all(
                    "SELECT * FROM jobs WHERE machine = %s AND sha256 = %s AND seq != %s"
                    " AND state IN ('QUEUED', 'SENDING') ORDER BY seq FOR UPDATE",
                    (job.machine, job.sha256, seq),
                )
            ]
            if earlier and (duplicates == "skip" or any(e.state is S.SENDING for e in earlier)):
                first = earlier[0]
                reason = f"duplicate of {first.id} ({first.filename}), which is {first.state.value.lower()}"
                tx.execute("DELETE FROM job_programs WHERE seq = %s", (seq,))
                return self._move(tx, seq, S.REJECTED, reason, expect=(S.VALIDATED,)), []
            for old in earlier:
                replaced.append(
                    self._move(tx, old.seq, S.CANCELLED, f"replaced by {job.id}", expect=(S.QUEUED,))
                )
            return self._move(tx, seq, S.QUEUED, "", expect=(S.VALIDATED,), next_attempt_at=None), replaced

    @staticmethod
    def _store_program(tx: Transaction, seq: int, program: Path, size: int, sha256: str) -> None:
        """The program's bytes as rows of PROGRAM_CHUNK, read from its file a chunk at a time."""
        digest = hashlib.sha256()
        total = 0
        tx.execute("DELETE FROM job_programs WHERE seq = %s", (seq,))  # an earlier, interrupted accept
        with program.open("rb") as f:
            part = 0
            while chunk := f.read(PROGRAM_CHUNK):
                digest.update(chunk)
                total += len(chunk)
                tx.execute(
                    "INSERT INTO job_programs (seq, part, data) VALUES (%s, %s, %s)", (seq, part, chunk)
                )
                part += 1
        if total != size or digest.hexdigest() != sha256:
            raise JobError(
                f"{job_id(seq)}: the program {program} changed after validation"
                f" ({total} bytes, SHA-256 {digest.hexdigest()}; validated: {size} bytes, {sha256})"
            )

    def program_chunks(self, seq: int) -> Iterator[bytes]:
        """The stored program of job `seq`, a chunk at a time, each read in a transaction of its own (the
        connection is free between chunks). JobError if none is stored. The caller checks the SHA-256."""
        part = 0
        while True:
            with self.db.transaction() as tx:
                data = tx.scalar("SELECT data FROM job_programs WHERE seq = %s AND part = %s", (seq, part))
            if data is None:
                if part == 0:
                    raise JobError(f"{job_id(seq)} has no program in the job queue's database at {self}")
                return
            yield data
            part += 1

    def received_here(self, serves: Sequence[str] = (), limit: int = 10_000) -> builtins.list[Job]:
        """Jobs still RECEIVED that this process's intake took in (their uploads are in its spool), and
        those of the machines it `serves` received before intakes were named (schema 1: each shard's
        inbox took only its own machines' jobs)."""
        with self.db.transaction() as tx:
            rows = tx.all(
                "SELECT * FROM jobs WHERE state = 'RECEIVED'"
                " AND (received_by = %s OR (received_by = '' AND machine = ANY(%s)))"
                " ORDER BY seq LIMIT %s",
                (self.received_by, list(serves), limit),
            )
        return [_job(r) for r in rows]

    def head(self, machine: str) -> Job | None:
        """The job a machine's worker handles next: SENDING (after a crash) first, then by priority, FIFO."""
        with self.db.transaction() as tx:
            row = tx.one(
                "SELECT * FROM jobs WHERE machine = %s AND state IN ('SENDING', 'QUEUED')"
                " ORDER BY state = 'SENDING' DESC, priority DESC, seq LIMIT 1",
                (machine,),
            )
        return _job(row) if row else None

    def start_sending(self, seq: int, reason: str = "", *, fence: Fence | None = None) -> Job:
        """QUEUED -> SENDING, counting the attempt: the claim. JobError if another process (or the CLI)
        changed it meanwhile, or if `fence` is not the machine's current lease."""
        with self._write() as tx:
            job = self._get(tx, seq, lock=True)
            self._fenced(tx, fence, job, "start sending")
            return self._move(tx, seq, S.SENDING, reason, expect=(S.QUEUED,), attempts=job.attempts + 1)

    def delivered(self, seq: int, name: str, reason: str = "", *, fence: Fence | None = None) -> Job:
        """SENDING -> DELIVERED; the stored program goes in the same transaction (its copy is on the
        controller, and in the delivering process's spool where its machine keeps delivered programs)."""
        with self._write() as tx:
            self._fenced(tx, fence, self._get(tx, seq, lock=True), "record the delivery of")
            tx.execute("DELETE FROM job_programs WHERE seq = %s", (seq,))
            return self._move(
                tx,
                seq,
                S.DELIVERED,
                reason,
                expect=(S.SENDING,),
                delivered_name=name,
                delivered_at=self._now(),
                next_attempt_at=None,
            )

    def send_failed(
        self, seq: int, reason: str, *, retry_at: float | None, fence: Fence | None = None
    ) -> Job:
        """A failed attempt: back to QUEUED until `retry_at`, or FAILED (dead letter) when None. Fenced like
        the claim: a holder that lost the machine must not put back a job the new holder is sending."""
        with self._write() as tx:
            self._fenced(tx, fence, self._get(tx, seq, lock=True), "record a failed attempt of")
            if retry_at is None:
                return self._move(tx, seq, S.FAILED, reason, expect=(S.SENDING,), next_attempt_at=None)
            return self._move(tx, seq, S.QUEUED, reason, expect=(S.SENDING,), next_attempt_at=retry_at)

    def note(self, seq: int, reason: str) -> Job:
        """Change a job's reason without changing its state (auto-start outcome, progress notes)."""
        with self._write() as tx:
            self._get(tx, seq, lock=True)
            rev = self._next_rev(tx)
            tx.execute(
                "UPDATE jobs SET reason = %s, rev = %s, updated_at = %s WHERE seq = %s",
                (reason, rev, self._now(), seq),
            )
            return self._get(tx, seq)

    # --- operator actions (CLI) --------------------------------------------------------------------

    def retry(self, seq: int, by: str = "") -> Job:
        with self._write() as tx:
            job = self._get(tx, seq, lock=True)
            if job.state not in (S.FAILED, S.CANCELLED):
                raise JobError(f"{job.id} is {job.state}; only FAILED or CANCELLED jobs can be retried")
            reason = f"retry requested{' by ' + by if by else ''}"
            return self._move(
                tx, seq, S.QUEUED, reason, expect=(S.FAILED, S.CANCELLED), attempts=0, next_attempt_at=None
            )

    def cancel(self, seq: int, by: str = "") -> Job:
        with self._write() as tx:
            job = self._get(tx, seq, lock=True)
            if job.state is S.SENDING:
                raise JobError(
                    f"{job.id} is being sent right now; delete the program on the controller afterwards"
                )
            if job.state in TERMINAL:
                raise JobError(f"{job.id} is already {job.state}")
            reason = f"cancelled{' by ' + by if by else ''}"
            return self._move(tx, seq, S.CANCELLED, reason, expect=(S.RECEIVED, S.VALIDATED, S.QUEUED))

    def set_priority(self, seq: int, priority: int) -> Job:
        with self._write() as tx:
            job = self._get(tx, seq, lock=True)
            if job.state in TERMINAL or job.state is S.SENDING:
                raise JobError(f"{job.id} is {job.state}; only waiting jobs can change priority")
            rev = self._next_rev(tx)
            tx.execute("UPDATE jobs SET priority = %s, rev = %s WHERE seq = %s", (priority, rev, seq))
            return self._get(tx, seq)

    # --- reading --------------------------------------------------------------------------------

    def get(self, seq: int) -> Job:
        with self.db.transaction() as tx:
            return self._get(tx, seq)

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
        with self.db.transaction() as tx:
            rows = tx.all(f"SELECT * FROM jobs{where} ORDER BY seq {order} LIMIT %s", (*args, limit))
        return [_job(r) for r in rows]

    def count(self, *, machine: str | None = None, states: Sequence[JobState] = ()) -> int:
        where, args = self._filter(machine, states)
        with self.db.transaction() as tx:
            return int(tx.scalar(f"SELECT COUNT(*) FROM jobs{where}", args))

    def latest(self, machine: str, state: JobState) -> Job | None:
        with self.db.transaction() as tx:
            row = tx.one(
                "SELECT * FROM jobs WHERE machine = %s AND state = %s"
                " ORDER BY updated_at DESC, seq DESC LIMIT 1",
                (machine, state.value),
            )
        return _job(row) if row else None

    def history(self, seq: int) -> builtins.list[Transition]:
        with self.db.transaction() as tx:
            rows = tx.all(
                "SELECT t.*, j.machine FROM transitions t JOIN jobs j ON j.seq = t.seq"
                " WHERE t.seq = %s ORDER BY t.id",
                (seq,),
            )
        return [_transition(r) for r in rows]

    def changes_since(self, rev: int) -> builtins.list[Job]:
        """Jobs changed after revision `rev` (by this process or another), oldest change first."""
        with self.db.transaction() as tx:
            rows = tx.all("SELECT * FROM jobs WHERE rev > %s ORDER BY rev", (rev,))
        return [_job(r) for r in rows]

    def transitions_since(self, last_id: int) -> builtins.list[Transition]:
        with self.db.transaction() as tx:
            rows = tx.all(
                "SELECT t.*, j.machine FROM transitions t JOIN jobs j ON j.seq = t.seq"
                " WHERE t.id > %s ORDER BY t.id",
                (last_id,),
            )
        return [_transition(r) for r in rows]

    def marks(self) -> tuple[int, int]:
        """(latest revision, latest transition id): where a reader starts following changes."""
        with self.db.transaction() as tx:
            row = tx.one(
                "SELECT (SELECT value FROM meta WHERE key = 'rev') AS rev,"
                " (SELECT COALESCE(MAX(id), 0) FROM transitions) AS tid"
            )
        assert row is not None
        return int(row["rev"]), int(row["tid"])

    def data_version(self) -> int:
        """Moves whenever anyone commits a change to the queue (the revision)."""
        with self.db.transaction() as tx:
            return int(tx.scalar("SELECT value FROM meta WHERE key = 'rev'"))

    @staticmethod
    def _filter(machine: str | None, states: Sequence[JobState]) -> tuple[str, tuple[Any, ...]]:
        clauses: builtins.list[str] = []
        args: builtins.list[Any] = []
        if machine is not None:
            clauses.append("machine = %s")
            args.append(machine)
        if states:
            clauses.append("state = ANY(%s)")
            args.append([s.value for s in states])
        return (" WHERE " + " AND ".join(clauses) if clauses else ""), tuple(args)
