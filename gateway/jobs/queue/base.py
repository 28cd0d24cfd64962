"""JobStore: what the gateway needs of a durable job queue, whichever database keeps it.

Two stores fit it: `JobQueue` (store.py), one SQLite file in the state directory, the
embedded default; and `PostgresJobQueue` (postgres.py), a PostgreSQL database that several
gateway processes (shards) share. Both keep the same states and transitions
(records.py), compare-and-set every change in one transaction with its transition row and
a new revision, and let a reader follow changes by revision (`marks`, `changes_since`,
`transitions_since`, `data_version`). Methods are synchronous; the async side calls them in
a worker thread (gateway/jobs/threads.py).

`fence`: the claim of a job (`start_sending`) and its outcome (`delivered`, `send_failed`) can carry the
fencing token of the claimer's lease on the machine; a store that holds leases checks it in
the same transaction and refuses a stale one (JobError). The SQLite store holds no leases
and refuses a fence: one process owns a SQLite queue.

`shares_programs`: the PostgreSQL store also carries each queued job's program (given to `accept`,
read back with `program_chunks`, gone when the job is DELIVERED), so that any shard delivers a job
any shard took in; the SQLite store leaves programs to the spool of its one process.
"""

from __future__ import annotations

import builtins
from collections.abc import Iterator, Sequence
from pathlib import Path
from typing import Any, Literal, Protocol, Self

from gateway.jobs.queue.records import Job, JobState, Transition
from gateway.shards.fence import Fence


class JobStore(Protocol):
    """The durable queue, as the job service, the delivery workers and `cnc-gateway jobs` use it."""

    shares_programs: bool  # True: the queue carries the programs (PostgreSQL), any shard reads them

    def open(self) -> Self: ...

    def close(self) -> None: ...

    def __enter__(self) -> Self: ...

    def __exit__(self, *exc_info: object) -> None: ...

    # --- the pipeline
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
    ) -> Job: ...

    def reject(self, seq: int, reason: str) -> Job: ...

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
    ) -> tuple[Job, builtins.list[Job]]: ...

    def program_chunks(self, seq: int) -> Iterator[bytes]: ...

    def received_here(self, serves: Sequence[str] = (), limit: int = 10_000) -> builtins.list[Job]: ...

    def head(self, machine: str) -> Job | None: ...

    def start_sending(self, seq: int, reason: str = "", *, fence: Fence | None = None) -> Job: ...

    def delivered(self, seq: int, name: str, reason: str = "", *, fence: Fence | None = None) -> Job: ...

    def send_failed(
        self, seq: int, reason: str, *, retry_at: float | None, fence: Fence | None = None
    ) -> Job: ...

    def note(self, seq: int, reason: str) -> Job: ...

    # --- operator actions
    def retry(self, seq: int, by: str = "") -> Job: ...

    def cancel(self, seq: int, by: str = "") -> Job: ...

    def set_priority(self, seq: int, priority: int) -> Job: ...

    # --- reading
    def get(self, seq: int) -> Job: ...

    def list(
        self,
        *,
        machine: str | None = None,
        states: Sequence[JobState] = (),
        limit: int = 50,
        newest_first: bool = True,
    ) -> builtins.list[Job]: ...

    def count(self, *, machine: str | None = None, states: Sequence[JobState] = ()) -> int: ...

    def latest(self, machine: str, state: JobState) -> Job | None: ...

    def history(self, seq: int) -> builtins.list[Transition]: ...

    def changes_since(self, rev: int) -> builtins.list[Job]: ...

    def transitions_since(self, last_id: int) -> builtins.list[Transition]: ...

    def marks(self) -> tuple[int, int]: ...

    def data_version(self) -> int: ...
