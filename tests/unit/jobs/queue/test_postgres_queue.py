"""The job queue in PostgreSQL: what sharing it across processes adds to the SQLite file's behaviour.

Claims are exactly-once between processes (real ones, and many connections at once); the schema is
migrated by a newer gateway and refused by an older one; a dropped connection is opened again; an
unreachable database is a clear error without the password.
"""

from __future__ import annotations

import multiprocessing
import threading
from collections import Counter
from collections.abc import Iterator

import psycopg
import pytest

from gateway.errors import JobError, JobStoreError, StoreError
from gateway.jobs.queue.postgres import COMPONENT, MIGRATIONS, PostgresJobQueue
from gateway.jobs.queue.records import JobState

S = JobState
MACHINES = ("laser", "plasma", "punch")


@pytest.fixture
def queue(postgres_url: str) -> Iterator[PostgresJobQueue]:
    with PostgresJobQueue(postgres_url) as q:
        yield q


def fill(q: PostgresJobQueue, per_machine: int) -> list[int]:
    seqs = []
    for machine in MACHINES:
        for i in range(per_machine):
            job = q.receive(machine, f"p{i}.nc", 10, f"{machine}-{i}")
            q.accept(job.seq, duplicates="skip", program_size=10, program_sha256=job.sha256)
            seqs.append(job.seq)
    return seqs


def drain(url: str, machines: tuple[str, ...], claimed: list[int]) -> None:
    """One worker (thread or process): claim each machine's head, deliver it, until nothing is left."""
    with PostgresJobQueue(url) as q:
        idle = False
        while not idle:
            idle = True
            for machine in machines:
                job = q.head(machine)
                if job is None or job.state is not S.QUEUED:
                    continue
                idle = False
                try:
                    q.start_sending(job.seq)
                except JobError:  # another worker claimed it first
                    continue
                claimed.append(job.seq)
                q.delivered(job.seq, job.filename)


def _drain_in_process(url: str, out: multiprocessing.Queue[list[int]]) -> None:
    claimed: list[int] = []
    drain(url, MACHINES, claimed)
    out.put(claimed)


def test_workers_on_many_connections_claim_every_job_exactly_once(
    queue: PostgresJobQueue, postgres_url: str
) -> None:
    seqs = fill(queue, 20)
    claims: list[list[int]] = [[] for _ in range(6)]
    workers = [threading.Thread(target=drain, args=(postgres_url, MACHINES, c)) for c in claims]
    for w in workers:
        w.start()
    for w in workers:
        w.join(timeout=120)
    counted = Counter(seq for c in claims for seq in c)
    assert sorted(counted) == sorted(seqs) and set(counted.values()) == {1}
    assert queue.count(states=(S.DELIVERED,)) == len(seqs)
    for seq in seqs:  # one SENDING and one DELIVERED in each job's history: no second send
        states = [t.state for t in queue.history(seq)]
        assert states.count(S.SENDING) == 1 and states.count(S.DELIVERED) == 1


def test_two_processes_claim_every_job_exactly_once(queue: PostgresJobQueue, postgres_url: str) -> None:
    seqs = fill(queue, 30)
    context = multiprocessing.get_context("spawn")
    out: multiprocessing.Queue[list[int]] = context.Queue()
    procs = [context.Process(target=_drain_in_process, args=(postgres_url, out)) for _ in range(2)]
    for p in procs:
        p.start()
    results = [out.get(timeout=120) for _ in procs]
    for p in procs:
        p.join(timeout=30)
        assert p.exitcode == 0
    counted = Counter(seq for r in results for seq in r)
    assert sorted(counted) == sorted(seqs) and set(counted.values()) == {1}


def test_two_connections_racing_for_one_job_give_it_to_one(
    queue: PostgresJobQueue, postgres_url: str
) -> None:
    for round_ in range(20):
        job = queue.receive("laser", "race.nc", 1, f"race-{round_}")
        queue.accept(job.seq, duplicates="skip", program_size=1, program_sha256=job.sha256)
        barrier = threading.Barrier(4)
        outcomes: list[str] = []

        def claim(
            seq: int = job.seq, barrier: threading.Barrier = barrier, outcomes: list[str] = outcomes
        ) -> None:
            with PostgresJobQueue(postgres_url) as q:
                barrier.wait()
                try:
                    q.start_sending(seq)
                    outcomes.append("claimed")
                except JobError:
                    outcomes.append("refused")

        threads = [threading.Thread(target=claim) for _ in range(4)]
        for t in threads:
            t.start()
        for t in threads:
            t.join(timeout=60)
        assert sorted(outcomes) == ["claimed", "refused", "refused", "refused"]
        assert queue.get(job.seq).attempts == 1
        queue.delivered(job.seq, "race.nc")


def test_changes_made_elsewhere_are_followed_in_commit_order(
    queue: PostgresJobQueue, postgres_url: str
) -> None:
    rev, tid = queue.marks()
    with PostgresJobQueue(postgres_url) as other:
        fill(other, 2)
    changed = queue.changes_since(rev)
    assert [j.rev for j in changed] == sorted(j.rev for j in changed)
    transitions = queue.transitions_since(tid)
    assert len(transitions) == 3 * len(changed) and [t.id for t in transitions] == sorted(
        t.id for t in transitions
    )


def test_the_schema_is_versioned_and_a_newer_one_is_refused(postgres_url: str) -> None:
    with PostgresJobQueue(postgres_url) as q:
        q.receive("laser", "a.nc", 1, "a")
    with PostgresJobQueue(postgres_url) as q:  # opening again migrates nothing and keeps the jobs
        assert q.count() == 1
    with psycopg.connect(postgres_url, autocommit=True) as conn:
        assert conn.execute(
            "SELECT version FROM schema_versions WHERE component = %s", (COMPONENT,)
        ).fetchone() == (len(MIGRATIONS),)
        conn.execute("UPDATE schema_versions SET version = 99 WHERE component = %s", (COMPONENT,))
    with pytest.raises(JobError, match=r"schema 99, from a newer cnc-gateway .*knows schema 2"):
        PostgresJobQueue(postgres_url).open()


def test_a_dropped_connection_is_opened_again(queue: PostgresJobQueue, postgres_url: str) -> None:
    seq = queue.receive("laser", "a.nc", 1, "a").seq
    queue.db.ping_after = 3600.0  # a connection in use: not tried before each operation
    with psycopg.connect(postgres_url, autocommit=True) as admin:
        admin.execute(
            "SELECT pg_terminate_backend(pid) FROM pg_stat_activity"
            " WHERE datname = current_database() AND pid <> pg_backend_pid()"
        )
    with pytest.raises(JobStoreError):  # the call that finds the connection gone says so
        queue.get(seq)
    assert queue.get(seq).filename == "a.nc"  # and the next one reconnects


def test_an_idle_connection_the_server_dropped_is_replaced_before_use(postgres_url: str) -> None:
    with PostgresJobQueue(postgres_url) as queue:
        seq = queue.receive("laser", "a.nc", 1, "a").seq
        queue.db.ping_after = 0.0  # as if idle for longer than ping_after
        with psycopg.connect(postgres_url, autocommit=True) as admin:
            admin.execute(
                "SELECT pg_terminate_backend(pid) FROM pg_stat_activity"
                " WHERE datname = current_database() AND pid <> pg_backend_pid()"
            )
        assert queue.get(seq).filename == "a.nc"  # no error: the dead connection was found and replaced


def test_an_unreachable_database_is_a_clear_error_without_the_password(unused_port: int) -> None:
    url = f"postgresql://gw:s3cret@127.0.0.1:{unused_port}/plant"
    with pytest.raises(StoreError) as info:
        PostgresJobQueue(url).open()
    message = str(info.value)
    assert "cannot reach the job queue" in message and "127.0.0.1" in message
    assert "s3cret" not in message and "***" in message
    assert isinstance(info.value, JobError)  # the service refuses to start on it as on a bad queue file


def test_times_come_back_in_utc_whatever_the_servers_zone(postgres_url: str) -> None:
    with psycopg.connect(postgres_url, autocommit=True) as admin:
        name = admin.execute("SELECT current_database()").fetchone()
        assert name is not None
        admin.execute(f"ALTER DATABASE \"{name[0]}\" SET timezone = 'Asia/Tokyo'".encode())
    with PostgresJobQueue(postgres_url) as q:
        job = q.receive("laser", "a.nc", 1, "a")
        assert job.received_at.utcoffset() is not None and job.received_at.utcoffset().total_seconds() == 0
        assert job.as_dict()["received_at"].endswith("+00:00")
