"""Two shards share one machine's PostgreSQL queue: the one that holds the lease delivers, and when it
dies the other takes the machine over and delivers the rest; every job reaches the controller once.

Each shard here is what a gateway process would run for the machine: a LeaseHolder (the lease, renewed
in the background) and a DeliveryWorker with the real FTP transport, on a connection of its own to the
queue. A shard "dies" by having its tasks cancelled without releasing anything, as SIGKILL would leave it.
"""

from __future__ import annotations

import asyncio
import contextlib
import hashlib
from collections.abc import AsyncIterator, Callable
from pathlib import Path
from typing import Any

from gateway.config.loader import load_mapping
from gateway.jobs.delivery.worker import DeliveryWorker
from gateway.jobs.queue.postgres import PostgresJobQueue
from gateway.jobs.queue.publish import JobPublisher
from gateway.jobs.queue.records import Job, JobState
from gateway.jobs.service import Spool
from gateway.model.tree import VariableTree
from gateway.shards.holder import LeaseHolder
from gateway.transports.ftp.config import ControllerFtp
from gateway.transports.ftp.transport import FtpTransport
from tests.integration.jobs.conftest import Store, mapping_text, program
from tests.waiting import wait_until

S = JobState
LEASE = 1.5


class Shard:
    def __init__(self, name: str, url: str, mapping_file: Path, spool: Spool) -> None:
        mapping = load_mapping(mapping_file, environ={})
        assert mapping.jobs is not None
        controller = mapping.jobs.controller
        assert isinstance(controller, ControllerFtp)
        self.name = name
        self.queue = PostgresJobQueue(url)
        self.holder = LeaseHolder(url, name, ["laser"], lease_time=LEASE)
        tree = VariableTree([mapping.definition()])
        self.worker = DeliveryWorker(
            "laser",
            mapping.jobs,
            self.queue,
            spool,
            JobPublisher(tree, {"laser": mapping.jobs}),
            self.call,
            FtpTransport(controller, verify=mapping.jobs.verify),
            lease=self.holder,
        )
        self.tasks: list[asyncio.Task[Any]] = []

    async def call(self, fn: Callable[..., Any], *args: Any, **kwargs: Any) -> Any:
        return await asyncio.to_thread(fn, *args, **kwargs)

    @contextlib.asynccontextmanager
    async def running(self) -> AsyncIterator[Shard]:
        self.queue.open()
        try:
            async with self.holder:
                self.tasks = [
                    asyncio.create_task(self.holder.run(), name=f"{self.name}:leases"),
                    asyncio.create_task(self.worker.run(), name=f"{self.name}:laser"),
                ]
                try:
                    yield self
                finally:
                    await self.kill()
        finally:
            self.queue.close()

    async def kill(self) -> None:
        for task in self.tasks:
            task.cancel()
        await asyncio.gather(*self.tasks, return_exceptions=True)
        self.tasks = []


def submit(queue: PostgresJobQueue, spool: Spool, tag: str) -> Job:
    data = program(tag)
    digest = hashlib.sha256(data).hexdigest()
    job = queue.receive("laser", f"{tag}.nc", len(data), digest)
    spool.program(job).write_bytes(data)
    job, _ = queue.accept(job.seq, duplicates="skip", program_size=len(data), program_sha256=digest)
    return job


async def delivered(queue: PostgresJobQueue, jobs: list[Job]) -> None:
    def done() -> bool:
        return all(queue.get(j.seq).state is S.DELIVERED for j in jobs)

    await wait_until(done, timeout=30, message=f"{[j.id for j in jobs]} delivered")


async def test_the_lease_holder_delivers_and_the_other_shard_takes_over_when_it_dies(
    store: Store, postgres_url: str, tmp_path: Path, renames
) -> None:
    mapping_file = tmp_path / "laser.yaml"
    mapping_file.write_text(mapping_text("laser", store.port))
    spool = Spool(tmp_path / "spool")  # one host, one state directory: the spool is shared
    spool.root.mkdir()
    first = Shard("gw-a", postgres_url, mapping_file, spool)
    second = Shard("gw-b", postgres_url, mapping_file, spool)
    with PostgresJobQueue(postgres_url) as queue:
        async with first.running(), second.running():
            assert first.holder.held() == ["laser"] and second.holder.held() == []
            token = first.holder.fence("laser")
            before = [submit(queue, spool, f"a{i}") for i in range(3)]
            await delivered(queue, before)
            await first.kill()  # gw-a dies: it stops renewing, releases nothing
            after = [submit(queue, spool, f"b{i}") for i in range(3)]
            await delivered(queue, after)
            assert second.holder.held() == ["laser"]
            taken = second.holder.fence("laser")
            assert token is not None and taken is not None and taken.token > token.token
        jobs = [*before, *after]
        for job in jobs:  # one claim and one delivery each
            states = [t.state for t in queue.history(job.seq)]
            assert states.count(S.SENDING) == 1 and states.count(S.DELIVERED) == 1, states
    assert sorted(renames.targets) == sorted(j.filename for j in jobs)  # each reached the controller once
    assert set(store.files()) >= {j.filename for j in jobs}
