"""The delivery worker through the transport seam alone: a fake transport, a real queue and publisher.

What the worker owes every transport: it hands over the validated program (name, file, size,
SHA-256), publishes the progress the transport reports, records where the program went, fails
at once on a permanent refusal and retries otherwise, and after a crash asks `holds()` before
sending anything again.
"""

from __future__ import annotations

import asyncio
import hashlib
from collections.abc import Callable, Iterator, Mapping
from pathlib import Path
from typing import Any

import pytest

from gateway.config.jobs import JobsConfig
from gateway.config.mapping import MachineMapping
from gateway.errors import DeliveryError
from gateway.jobs.delivery.worker import DeliveryWorker
from gateway.jobs.queue.publish import JobPublisher
from gateway.jobs.queue.store import Job, JobQueue, JobState
from gateway.model.tree import VariableTree
from gateway.transports.base import DeliveryTransport, Program, Progress, ReportProgress

CONTENT = b"G1 X10 F100\nM30\n"
DIGEST = hashlib.sha256(CONTENT).hexdigest()


class FakeTransport:
    """Records what it is given; `fail` decides each delivery's outcome, `found` what `holds` says."""

    def __init__(
        self, fail: Callable[[int], DeliveryError | None] = lambda n: None, found: bool = False
    ) -> None:
        self.fail = fail
        self.found = found
        self.delivered: list[Program] = []
        self.asked: list[Program] = []
        self.attempts = 0

    async def deliver(self, program: Program, progress: ReportProgress) -> str:
        self.attempts += 1
        assert program.path.read_bytes() == CONTENT  # the spooled program, readable
        progress(Progress(program.size // 2))
        error = self.fail(self.attempts)
        if error is not None:
            raise error
        progress(Progress(program.size, block=2, lead=1.5))
        self.delivered.append(program)
        return f"fake:{program.name}"

    async def holds(self, program: Program) -> bool:
        self.asked.append(program)
        return self.found


class Spool:
    def __init__(self, root: Path) -> None:
        self.root = root

    def program(self, job: Job) -> Path:
        return self.root / f"{job.id}.program"

    def discard(self, job: Job) -> None:
        self.program(job).unlink(missing_ok=True)

    def delivered(self, job: Job) -> None:
        self.discard(job)


class Rig:
    def __init__(self, tmp_path: Path, transport: DeliveryTransport, **jobs: Any) -> None:
        config = JobsConfig.model_validate({"controller": {"host": "127.0.0.1"}, **jobs})
        mapping = MachineMapping.model_validate(
            {
                "machine": "m1",
                "driver": {"endpoint": "opc.tcp://127.0.0.1:4841"},
                "variables": [{"path": "State", "source": "s", "type": "Int16"}],
            }
        )
        self.tree = VariableTree([mapping.definition()])
        self.events = self.tree.events.subscribe("test")
        self.queue = JobQueue(tmp_path / "q.sqlite3").open()
        self.spool = Spool(tmp_path)
        self.publisher = JobPublisher(self.tree, {"m1": config})
        self.worker = DeliveryWorker(
            "m1", config, self.queue, self.spool, self.publisher, self.call, transport
        )

    async def call(self, fn: Callable[..., Any], *args: Any, **kwargs: Any) -> Any:
        return fn(*args, **kwargs)

    def queued(self) -> Job:
        job = self.queue.receive("m1", "part.nc", len(CONTENT), DIGEST, user="nest", origin="ftp")
        self.spool.program(job).write_bytes(CONTENT)
        job, _ = self.queue.accept(
            job.seq, duplicates="skip", program_size=len(CONTENT), program_sha256=DIGEST, program_name="O1234"
        )
        return job

    def progress_published(self, job: Job) -> list[Any]:
        """The progress in the job's retained records, in order."""
        records = [e.payload for e in self.events.take() if e.channel == f"jobs/{job.id}"]
        return [r["progress"] for r in records if isinstance(r, Mapping)]


@pytest.fixture
def rigs(tmp_path: Path) -> Iterator[Callable[..., Rig]]:
    made: list[Rig] = []

    def make(transport: DeliveryTransport, **jobs: Any) -> Rig:
        made.append(Rig(tmp_path, transport, **jobs))
        return made[-1]

    yield make
    for rig in made:
        rig.queue.close()


async def test_the_transport_gets_the_validated_program_and_says_where_it_went(
    rigs: Callable[..., Rig],
) -> None:
    transport = FakeTransport()
    rig = rigs(transport)
    job = rig.queued()
    await rig.worker.deliver(job)
    (program,) = transport.delivered
    assert (program.name, program.size, program.sha256, program.number) == (
        "part.nc",
        len(CONTENT),
        DIGEST,
        "O1234",
    )
    done = rig.queue.get(job.seq)
    assert done.state is JobState.DELIVERED and done.reason.startswith("delivered to fake:part.nc in ")
    assert not rig.spool.program(job).exists()  # delivered: the spool copy goes
    assert rig.progress_published(job) == [0.0, 100.0]  # the half-way report falls within PROGRESS_EVERY
    assert rig.publisher.vars["m1"].progress.sample.value == 100.0


async def test_a_permanent_refusal_fails_the_job_at_once(rigs: Callable[..., Rig]) -> None:
    transport = FakeTransport(fail=lambda n: DeliveryError("553 name not allowed", permanent=True))
    rig = rigs(transport, max_attempts=5)
    job = rig.queued()
    await rig.worker.deliver(job)
    failed = rig.queue.get(job.seq)
    assert failed.state is JobState.FAILED and failed.reason == "failed: 553 name not allowed"
    assert transport.attempts == 1


async def test_other_failures_are_retried_with_backoff(rigs: Callable[..., Rig]) -> None:
    transport = FakeTransport(fail=lambda n: DeliveryError("connection reset") if n == 1 else None)
    rig = rigs(transport, max_attempts=3, retry={"initial": 0.01, "max": 0.01})
    job = rig.queued()
    await rig.worker.deliver(job)
    again = rig.queue.get(job.seq)
    assert again.state is JobState.QUEUED and again.reason.startswith(
        "attempt 1 of 3 failed: connection reset"
    )
    await asyncio.sleep(0.02)
    await rig.worker.deliver(rig.queue.head("m1") or again)
    assert rig.queue.get(job.seq).state is JobState.DELIVERED and transport.attempts == 2


async def test_after_a_crash_a_program_the_controller_holds_is_not_sent_again(
    rigs: Callable[..., Rig],
) -> None:
    transport = FakeTransport(found=True)
    rig = rigs(transport)
    job = rig.queue.start_sending(rig.queued().seq)  # the earlier run died while sending
    await rig.worker.recover(job)
    assert [p.sha256 for p in transport.asked] == [DIGEST] and transport.delivered == []
    done = rig.queue.get(job.seq)
    assert (
        done.state is JobState.DELIVERED and done.reason == "found complete on the controller after a restart"
    )


async def test_after_a_crash_a_program_not_found_is_sent_again(rigs: Callable[..., Rig]) -> None:
    transport = FakeTransport(found=False)
    rig = rigs(transport)
    job = rig.queue.start_sending(rig.queued().seq)
    await rig.worker.recover(job)
    assert rig.queue.get(job.seq).state is JobState.QUEUED and transport.delivered == []
