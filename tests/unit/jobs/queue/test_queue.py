"""The durable queue: its state machine, duplicates, order, retries, and two processes on one queue.

Every test of the queue's behaviour runs against both stores: the SQLite file and PostgreSQL (a fresh
database per test, tests/postgres.py). The file's own matters (WAL, busy timeout, user_version) stay SQLite's.
"""

from __future__ import annotations

import json
import sqlite3
import threading
from collections.abc import Callable, Iterator
from pathlib import Path

import pytest

from gateway.errors import JobError
from gateway.jobs.queue.base import JobStore
from gateway.jobs.queue.postgres import PostgresJobQueue
from gateway.jobs.queue.store import ALLOWED, TERMINAL, JobQueue, JobState, job_id, parse_job_id

S = JobState


@pytest.fixture(params=["sqlite", "postgresql"])
def open_store(request: pytest.FixtureRequest, tmp_path: Path) -> Callable[[], JobStore]:
    """A new connection to this test's queue, in each store: every call another process's view."""
    if request.param == "sqlite":
        return lambda: JobQueue(tmp_path / "queue.sqlite3")
    url = request.getfixturevalue("postgres_url")
    return lambda: PostgresJobQueue(url)


@pytest.fixture
def queue(open_store: Callable[[], JobStore]) -> Iterator[JobStore]:
    with open_store() as q:
        yield q


def new(q: JobStore, machine: str = "laser", name: str = "a.nc", sha: str = "aa", priority: int = 0) -> int:
    return q.receive(machine, name, 10, sha, user="nest", origin="ftp", priority=priority).seq


def queued(
    q: JobStore,
    machine: str = "laser",
    name: str = "a.nc",
    sha: str = "aa",
    priority: int = 0,
    duplicates: str = "skip",
) -> int:
    seq = new(q, machine, name, sha, priority)
    job, _ = q.accept(seq, duplicates=duplicates, program_size=10, program_sha256=sha)  # type: ignore[arg-type]
    return job.seq


def test_a_new_job_is_received_with_a_stable_readable_id(open_store: Callable[[], JobStore]) -> None:
    with open_store() as q:
        job = q.receive("laser", "part.nc", 123, "ab" * 32, user="nest", origin="ftp 1.2.3.4")
        assert job.id == "J000001" and job.state is S.RECEIVED
        assert [t.state for t in q.history(job.seq)] == [S.RECEIVED]
    with open_store() as q:  # another run of the gateway
        assert q.get(1).filename == "part.nc"
        assert q.receive("laser", "b.nc", 1, "cd").id == "J000002"


def test_job_ids_parse_in_the_forms_people_type() -> None:
    assert parse_job_id("J000042") == parse_job_id("j42") == parse_job_id("42") == 42
    assert job_id(42) == "J000042"
    for bad in ("", "J", "x42", "J-1", "0"):
        with pytest.raises(JobError):
            parse_job_id(bad)


def test_the_happy_path_records_every_transition_with_reason_and_time(queue: JobStore) -> None:
    seq = new(queue)
    job, replaced = queue.accept(
        seq,
        duplicates="skip",
        program_size=9,
        program_sha256="bb",
        program_name="O1",
        estimate={"seconds": 1.5},
        warnings=("w1",),
        reason="valid",
    )
    assert job.state is S.QUEUED and replaced == []
    assert job.estimate == {"seconds": 1.5} and job.warnings == ("w1",) and job.program_name == "O1"
    job = queue.start_sending(seq)
    assert job.state is S.SENDING and job.attempts == 1
    job = queue.delivered(seq, "a.nc", "done")
    assert job.state is S.DELIVERED and job.delivered_name == "a.nc" and job.delivered_at is not None
    history = queue.history(seq)
    assert [(t.previous, t.state) for t in history] == [
        (None, S.RECEIVED),
        (S.RECEIVED, S.VALIDATED),
        (S.VALIDATED, S.QUEUED),
        (S.QUEUED, S.SENDING),
        (S.SENDING, S.DELIVERED),
    ]
    assert history[1].reason == "valid" and history[-1].reason == "done"
    assert all(t.ts.tzinfo is not None for t in history)
    json.dumps(job.as_dict())  # what MQTT publishes must serialise


@pytest.mark.parametrize(
    ("setup", "action"),
    [
        ("received", lambda q, s: q.start_sending(s)),
        ("received", lambda q, s: q.delivered(s, "x")),
        ("queued", lambda q, s: q.delivered(s, "x")),
        ("queued", lambda q, s: q.reject(s, "no")),
        ("queued", lambda q, s: q.retry(s)),
        ("sending", lambda q, s: q.cancel(s)),
        ("delivered", lambda q, s: q.retry(s)),
        ("delivered", lambda q, s: q.cancel(s)),
        ("delivered", lambda q, s: q.start_sending(s)),
    ],
)
def test_transitions_the_state_machine_does_not_allow_are_refused(
    queue: JobStore, setup: str, action
) -> None:
    seq = new(queue) if setup == "received" else queued(queue)
    if setup in ("sending", "delivered"):
        queue.start_sending(seq)
    if setup == "delivered":
        queue.delivered(seq, "a.nc")
    before = queue.get(seq)
    with pytest.raises(JobError):
        action(queue, seq)
    after = queue.get(seq)
    assert after.state is before.state and len(queue.history(seq)) == len(queue.history(seq))


def test_terminal_states_lead_nowhere_but_a_retry() -> None:
    for state in TERMINAL:
        assert ALLOWED[state] <= {S.QUEUED}
    assert ALLOWED[S.DELIVERED] == frozenset() and ALLOWED[S.REJECTED] == frozenset()


def test_rejection_keeps_the_reason(queue: JobStore) -> None:
    seq = new(queue)
    job = queue.reject(seq, "line 3: no M30")
    assert job.state is S.REJECTED and job.reason == "line 3: no M30"


def test_same_content_while_the_first_still_waits_is_skipped(queue: JobStore) -> None:
    first = queued(queue, sha="same")
    second = new(queue, name="copy.nc", sha="same")
    job, replaced = queue.accept(second, duplicates="skip", program_size=10, program_sha256="same")
    assert job.state is S.REJECTED and "duplicate of J000001" in job.reason and replaced == []
    assert queue.get(first).state is S.QUEUED


def test_replace_cancels_the_waiting_copy_and_queues_the_new_one(queue: JobStore) -> None:
    first = queued(queue, sha="same")
    second = new(queue, sha="same")
    job, replaced = queue.accept(second, duplicates="replace", program_size=10, program_sha256="same")
    assert job.state is S.QUEUED
    assert [r.seq for r in replaced] == [first]
    assert queue.get(first).state is S.CANCELLED and "replaced by J000002" in queue.get(first).reason


def test_a_copy_being_sent_cannot_be_replaced_so_the_new_one_is_a_duplicate(queue: JobStore) -> None:
    first = queued(queue, sha="same")
    queue.start_sending(first)
    second = new(queue, sha="same")
    job, _ = queue.accept(second, duplicates="replace", program_size=10, program_sha256="same")
    assert job.state is S.REJECTED and "sending" in job.reason
    assert queue.get(first).state is S.SENDING


def test_same_content_is_no_duplicate_once_delivered_or_for_another_machine(queue: JobStore) -> None:
    first = queued(queue, sha="same")
    queue.start_sending(first)
    queue.delivered(first, "a.nc")
    assert queue.get(queued(queue, sha="same")).state is S.QUEUED
    assert queue.get(queued(queue, machine="plasma", sha="same")).state is S.QUEUED


def test_fifo_per_machine_with_priority_first_and_an_interrupted_send_before_all(queue: JobStore) -> None:
    a = queued(queue, name="a.nc", sha="1")
    b = queued(queue, name="b.nc", sha="2")
    other = queued(queue, machine="plasma", sha="3")
    assert queue.head("laser").seq == a
    urgent = queued(queue, name="urgent.nc", sha="4", priority=5)
    assert queue.head("laser").seq == urgent
    assert queue.head("plasma").seq == other
    queue.start_sending(b)  # e.g. a run that was killed while sending b
    assert queue.head("laser").seq == b
    queue.delivered(b, "b.nc")
    order = []
    while (job := queue.head("laser")) is not None:
        order.append(job.seq)
        queue.start_sending(job.seq)
        queue.delivered(job.seq, job.filename)
    assert order == [urgent, a]
    assert queue.head("nothing") is None


def test_priority_of_a_waiting_job_can_change(queue: JobStore) -> None:
    a = queued(queue, sha="1")
    b = queued(queue, sha="2")
    queue.set_priority(b, 3)
    assert queue.head("laser").seq == b
    queue.start_sending(b)
    with pytest.raises(JobError):
        queue.set_priority(b, 1)
    assert queue.get(a).priority == 0


def test_failed_attempts_retry_later_then_fail_and_an_operator_can_retry(queue: JobStore) -> None:
    seq = queued(queue)
    queue.start_sending(seq)
    job = queue.send_failed(seq, "connection refused", retry_at=1234.5)
    assert job.state is S.QUEUED and job.next_attempt_at == 1234.5 and job.attempts == 1
    queue.start_sending(seq)
    job = queue.send_failed(seq, "552 disk full", retry_at=None)
    assert job.state is S.FAILED and job.reason == "552 disk full" and job.attempts == 2
    job = queue.retry(seq, by="anna (cli)")
    assert job.state is S.QUEUED and job.attempts == 0 and job.next_attempt_at is None
    assert "anna" in job.reason


def test_cancel_waiting_jobs_and_retry_cancelled_ones(queue: JobStore) -> None:
    seq = queued(queue)
    job = queue.cancel(seq, by="ops")
    assert job.state is S.CANCELLED and "ops" in job.reason
    assert queue.head("laser") is None
    assert queue.retry(seq).state is S.QUEUED
    received = new(queue, sha="x")
    assert queue.cancel(received).state is S.CANCELLED


def test_note_changes_the_reason_only(queue: JobStore) -> None:
    seq = queued(queue)
    queue.start_sending(seq)
    queue.delivered(seq, "a.nc", "delivered")
    job = queue.note(seq, "delivered; started a.nc")
    assert job.state is S.DELIVERED and job.reason == "delivered; started a.nc"


def test_listing_counting_and_latest(queue: JobStore) -> None:
    a = queued(queue, sha="1")
    b = queued(queue, sha="2")
    queue.reject(new(queue, sha="3"), "bad")
    assert [j.seq for j in queue.list(limit=2)] == [3, b]
    assert queue.count(machine="laser", states=(S.QUEUED,)) == 2
    assert queue.latest("laser", S.REJECTED).seq == 3
    assert queue.latest("laser", S.DELIVERED) is None
    assert [j.seq for j in queue.list(states=(S.QUEUED,), newest_first=False)] == [a, b]


def test_changes_are_followed_by_revision_and_transition(queue: JobStore) -> None:
    rev, tid = queue.marks()
    seq = queued(queue)
    changed = queue.changes_since(rev)
    assert [j.seq for j in changed] == [seq] and changed[-1].state is S.QUEUED
    assert [t.state for t in queue.transitions_since(tid)] == [S.RECEIVED, S.VALIDATED, S.QUEUED]
    rev, tid = queue.marks()
    assert queue.changes_since(rev) == [] and queue.transitions_since(tid) == []


def test_a_second_process_sees_and_changes_the_same_queue(open_store: Callable[[], JobStore]) -> None:
    """The CLI and the running gateway share the queue: data_version, changes by revision, compare-and-set."""
    with open_store() as gateway, open_store() as cli:
        seq = queued(gateway)
        version = gateway.data_version()
        rev, _ = gateway.marks()
        cli.cancel(seq, by="cli")
        assert gateway.data_version() != version
        assert [j.state for j in gateway.changes_since(rev)] == [S.CANCELLED]
        with pytest.raises(JobError):  # the gateway's worker loses the race cleanly
            gateway.start_sending(seq)
    if isinstance(gateway, JobQueue):
        assert sqlite3.connect(gateway.path).execute("PRAGMA journal_mode").fetchone()[0] == "wal"


def test_a_writer_waits_for_another_writer_and_a_hopeless_wait_is_a_clear_error(tmp_path: Path) -> None:
    path = tmp_path / "q.sqlite3"
    with JobQueue(path) as q:
        seq = queued(q)
    holder = sqlite3.connect(path, isolation_level=None)
    holder.execute("BEGIN IMMEDIATE")
    with JobQueue(path, busy_timeout=0.05) as impatient, pytest.raises(JobError, match="busy"):
        impatient.cancel(seq)
    done = threading.Event()
    result: list[JobState] = []

    def cancel() -> None:
        with JobQueue(path, busy_timeout=30) as patient:
            result.append(patient.cancel(seq).state)
        done.set()

    worker = threading.Thread(target=cancel)
    worker.start()
    holder.execute("COMMIT")
    holder.close()
    assert done.wait(30)
    worker.join()
    assert result == [S.CANCELLED]


def test_a_queue_file_from_a_newer_version_is_refused(tmp_path: Path) -> None:
    path = tmp_path / "q.sqlite3"
    db = sqlite3.connect(path)
    db.execute("PRAGMA user_version=99")
    db.close()
    with pytest.raises(JobError, match="newer"):
        JobQueue(path).open()
