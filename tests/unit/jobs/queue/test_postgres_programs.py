"""The PostgreSQL queue carries each queued job's program (schema 2): stored in the transaction that queues
the job, read back a chunk at a time, gone when the job is delivered; a database of schema 1 is migrated
with its jobs kept, and one migrated further than this gateway knows is still refused.
"""

from __future__ import annotations

import hashlib
import os
import tracemalloc
from collections.abc import Iterator
from pathlib import Path

import psycopg
import pytest

from gateway.errors import JobError
from gateway.jobs.delivery.fetch import ProgramFetch
from gateway.jobs.queue import postgres
from gateway.jobs.queue.postgres import COMPONENT, MIGRATIONS, PostgresJobQueue
from gateway.jobs.queue.records import JobState

S = JobState


@pytest.fixture
def queue(postgres_url: str) -> Iterator[PostgresJobQueue]:
    with PostgresJobQueue(postgres_url, received_by="host-a:/state/1") as q:
        yield q


def a_program(tmp_path: Path, size: int, name: str = "p.program") -> tuple[Path, str]:
    path = tmp_path / name
    path.write_bytes(os.urandom(size))
    return path, hashlib.sha256(path.read_bytes()).hexdigest()


def queued(q: PostgresJobQueue, path: Path, digest: str, machine: str = "laser") -> int:
    size = path.stat().st_size
    job = q.receive(machine, "part.nc", size, digest)
    job, _ = q.accept(job.seq, duplicates="skip", program_size=size, program_sha256=digest, program=path)
    assert job.state is S.QUEUED
    return job.seq


def parts(url: str, seq: int) -> int:
    with psycopg.connect(url, autocommit=True) as conn:
        row = conn.execute("SELECT COUNT(*) FROM job_programs WHERE seq = %s", (seq,)).fetchone()
    assert row is not None
    return int(row[0])


def test_a_program_is_stored_in_chunks_and_read_back_whole(
    queue: PostgresJobQueue, postgres_url: str, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setattr(postgres, "PROGRAM_CHUNK", 4096)
    path, digest = a_program(tmp_path, 4096 * 5 + 17)
    seq = queued(queue, path, digest)
    assert parts(postgres_url, seq) == 6
    with PostgresJobQueue(postgres_url) as other:  # another shard's connection
        chunks = list(other.program_chunks(seq))
    assert max(len(c) for c in chunks) == 4096
    assert b"".join(chunks) == path.read_bytes()


def test_the_stored_program_goes_when_the_job_is_delivered_and_stays_when_it_fails(
    queue: PostgresJobQueue, postgres_url: str, tmp_path: Path
) -> None:
    path, digest = a_program(tmp_path, 1000)
    seq = queued(queue, path, digest)
    queue.start_sending(seq)
    queue.send_failed(seq, "the controller is away", retry_at=None)  # FAILED: kept for a retry
    assert parts(postgres_url, seq) == 1
    queue.retry(seq)
    queue.start_sending(seq)
    queue.delivered(seq, "part.nc")
    assert parts(postgres_url, seq) == 0
    with pytest.raises(JobError, match=r"J\d+ has no program in the job queue's database"):
        list(queue.program_chunks(seq))


def test_a_duplicate_rejected_at_accept_leaves_no_program(
    queue: PostgresJobQueue, postgres_url: str, tmp_path: Path
) -> None:
    path, digest = a_program(tmp_path, 100)
    first = queued(queue, path, digest)
    second = queue.receive("laser", "again.nc", 100, digest)
    job, _ = queue.accept(
        second.seq, duplicates="skip", program_size=100, program_sha256=digest, program=path
    )
    assert job.state is S.REJECTED and "duplicate of" in job.reason
    assert parts(postgres_url, first) == 1 and parts(postgres_url, second.seq) == 0


def test_a_program_that_changed_after_validation_is_not_queued(
    queue: PostgresJobQueue, postgres_url: str, tmp_path: Path
) -> None:
    path, digest = a_program(tmp_path, 100)
    job = queue.receive("laser", "part.nc", 100, digest)
    path.write_bytes(b"something else")
    with pytest.raises(JobError, match="changed after validation"):
        queue.accept(job.seq, duplicates="skip", program_size=100, program_sha256=digest, program=path)
    assert queue.get(job.seq).state is S.RECEIVED and parts(postgres_url, job.seq) == 0  # rolled back


def test_each_intake_resumes_only_what_it_received(postgres_url: str) -> None:
    with (
        PostgresJobQueue(postgres_url, received_by="host-a:/state/1") as one,
        PostgresJobQueue(postgres_url, received_by="host-b:/state/2") as two,
    ):
        mine = one.receive("laser-002", "a.nc", 1, "a").seq
        theirs = two.receive("laser-001", "b.nc", 1, "b").seq
        assert [j.seq for j in one.received_here()] == [mine]
        assert [j.seq for j in two.received_here()] == [theirs]


def test_a_schema_1_database_is_migrated_with_its_jobs(postgres_url: str, tmp_path: Path) -> None:
    with PostgresJobQueue(postgres_url) as q:
        old = q.receive("laser", "old.nc", 1, "a").seq
    with psycopg.connect(postgres_url, autocommit=True) as conn:  # back to what schema 1 had
        conn.execute("DROP TABLE job_programs")
        conn.execute("ALTER TABLE jobs DROP COLUMN received_by")
        conn.execute("UPDATE schema_versions SET version = 1 WHERE component = %s", (COMPONENT,))
    with PostgresJobQueue(postgres_url, received_by="host-a:/state/1") as q:
        assert q.get(old).filename == "old.nc"
        # Received before intakes were named: resumed by the shard that serves its machine.
        assert [j.seq for j in q.received_here(["laser"])] == [old]
        assert [j.seq for j in q.received_here(["plasma"])] == []
        path, digest = a_program(tmp_path, 300)
        seq = queued(q, path, digest)
        assert b"".join(q.program_chunks(seq)) == path.read_bytes()
    with psycopg.connect(postgres_url, autocommit=True) as conn:
        version = conn.execute(
            "SELECT version FROM schema_versions WHERE component = %s", (COMPONENT,)
        ).fetchone()
        assert version == (len(MIGRATIONS),) == (2,)
        conn.execute("UPDATE schema_versions SET version = 3 WHERE component = %s", (COMPONENT,))
    with pytest.raises(JobError, match=r"schema 3, from a newer cnc-gateway \(this one knows schema 2\)"):
        PostgresJobQueue(postgres_url).open()


def test_a_large_program_is_never_whole_in_memory(queue: PostgresJobQueue, tmp_path: Path) -> None:
    """16 MiB stored and read back (to a file, checked) with at most a few 1 MiB chunks allocated at once."""
    path, digest = a_program(tmp_path, 16 * 1024 * 1024)
    size = path.stat().st_size
    job = queue.receive("laser", "big.nc", size, digest)
    tracemalloc.start()
    try:
        job, _ = queue.accept(
            job.seq, duplicates="skip", program_size=size, program_sha256=digest, program=path
        )
        stored = tracemalloc.get_traced_memory()[1]
        tracemalloc.reset_peak()
        out = tmp_path / "fetched.program"
        ProgramFetch(queue, _no_loop).fetch(job, out)
        fetched = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert out.stat().st_size == size
    assert stored < 6 * postgres.PROGRAM_CHUNK and fetched < 6 * postgres.PROGRAM_CHUNK, (stored, fetched)


async def _no_loop(*args: object) -> None:  # ProgramFetch.fetch is called directly above
    raise AssertionError("not used")
