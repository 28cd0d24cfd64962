"""The delivery supervisor: every machine's delivery worker, its transports' own work, and the queue's
publication (what changed, from this process or the CLI's).

It owns the one `q()` every part of the job service changes the queue through, so that a change is
published soon after; `_watch` follows the queue file too, so that changes `cnc-gateway jobs …` makes
from another process are published and acted upon.
"""

from __future__ import annotations

import asyncio
import logging
from collections.abc import Callable, Sequence
from typing import Any, TypeVar

from gateway.errors import JobStoreError
from gateway.jobs.delivery.autostart import AutoStarter
from gateway.jobs.delivery.worker import DeliveryWorker
from gateway.jobs.queue.base import JobStore
from gateway.jobs.queue.publish import JobPublisher
from gateway.jobs.queue.store import JobState
from gateway.jobs.threads import JobThreads
from gateway.transports.base import Deliveries, Delivery

T = TypeVar("T")
log = logging.getLogger("gateway.jobs")
WATCH_INTERVAL = 1.0  # s between looks for changes made by other processes (the CLI)
ENDED_SWEEP = 200  # ended jobs past a machine's retained limit whose records are cleared at start-up


class DeliverySupervisor:
    """Runs deliveries and publishes the queue, for the machines in `publisher`."""

    def __init__(self, queue: JobStore, threads: JobThreads, publisher: JobPublisher) -> None:
        self.queue = queue
        self.threads = threads
        self.publisher = publisher
        self.machines: Sequence[str] = tuple(publisher.vars)
        self.workers: dict[str, DeliveryWorker] = {}
        self.autostarters: dict[str, AutoStarter] = {}
        self.deliveries: dict[str, Delivery] = {}  # each machine's, from its transport's `Deliveries`
        self.transports: dict[str, Deliveries] = {}  # by transport type, those in use
        self.processing: dict[str, int] = dict.fromkeys(self.machines, 0)  # uploads being taken in
        self._changed = asyncio.Event()
        self._rev = 0
        self._transition = 0

    def add(self, name: str, worker: DeliveryWorker, autostart: AutoStarter | None) -> None:
        self.workers[name] = worker
        if autostart is not None:
            self.autostarters[name] = autostart

    def wake(self, machine: str) -> None:
        """The machine's queue may have something for its worker."""
        worker = self.workers.get(machine)
        if worker is not None:
            worker.wake()

    def machine_busy(self, machine: str) -> bool:
        """True while a job for this machine is on its way or waiting to be started (for the demo)."""
        starter = self.autostarters.get(machine)
        publisher = self.publisher.vars.get(machine)
        waiting = bool(publisher.queue_length.sample.value) if publisher is not None else False
        return waiting or self.processing.get(machine, 0) > 0 or (starter is not None and starter.busy)

    # --- running -----------------------------------------------------------------------------------

    async def run(self) -> None:
        """Deliver and publish until cancelled."""
        async with asyncio.TaskGroup() as tg:
            for name, worker in self.workers.items():
                tg.create_task(worker.run(), name=f"jobs:deliver:{name}")
            tg.create_task(self._watch(), name="jobs:watch")
            for kind, transport in self.transports.items():
                tg.create_task(transport.run(), name=f"jobs:transport:{kind}")

    # --- publishing --------------------------------------------------------------------------------

    def changed(self) -> None:
        """Something in the queue changed: publish it soon."""
        self._changed.set()

    async def q(self, fn: Callable[..., T], *args: Any, **kwargs: Any) -> T:
        """A queue call in the queue's thread; what it changed is published soon."""
        result = await self.threads.queue(fn, *args, **kwargs)
        self.changed()
        return result

    async def _watch(self) -> None:
        """Publish what changed, and wake the workers on changes from elsewhere, every WATCH_INTERVAL.

        A queue whose database is away (PostgreSQL restarted, the network cut) is looked at again at the
        same pace, said once when it goes and once when it is back: the watcher outlives the outage, and
        with it the job service (a failing task would end the gateway's TaskGroup)."""
        version: int | None = None
        away: str | None = None
        while True:
            if version is not None:
                # asyncio.timeout, not wait_for: Python 3.11's wait_for can swallow a cancellation that
                # arrives as the event fires, and this loop would then never end.
                try:
                    async with asyncio.timeout(WATCH_INTERVAL):
                        await self._changed.wait()
                except TimeoutError:
                    pass
                self._changed.clear()
            try:
                current = await self.threads.queue(self.queue.data_version)
                if version is not None:
                    await self._sync()
            except JobStoreError as exc:
                if away is None:
                    log.warning(
                        "jobs: the job queue cannot be read (%s); again every %g s", exc, WATCH_INTERVAL
                    )
                away = str(exc)
                self._changed.clear()
                await asyncio.sleep(WATCH_INTERVAL)
                continue
            external = version is not None and (current != version or away is not None)
            version = current
            if away is not None:
                log.warning("jobs: the job queue can be read again")
                away = None
            if external:
                for worker in self.workers.values():
                    worker.wake()

    async def publish_all(self) -> None:
        """At start-up: every machine's summary, and the record of every job not yet finished."""
        self._rev, self._transition = await self.threads.queue(self.queue.marks)
        for name in self.machines:
            await self._summary(name)
        waiting = await self.threads.queue(
            self.queue.list,
            states=(JobState.RECEIVED, JobState.QUEUED, JobState.SENDING, JobState.FAILED),
            limit=1000,
        )
        for job in waiting:
            if job.machine in self.publisher.vars:
                self.publisher.job(job)
        for name in self.machines:  # records an earlier run left retained beyond the machine's limit
            ended = await self.threads.queue(
                self.queue.list,
                machine=name,
                states=(JobState.DELIVERED, JobState.REJECTED, JobState.CANCELLED),
                limit=self.publisher.keep[name] + ENDED_SWEEP,
            )
            self.publisher.ended_before(reversed(ended))

    async def _sync(self) -> None:
        jobs = await self.threads.queue(self.queue.changes_since, self._rev)
        transitions = await self.threads.queue(self.queue.transitions_since, self._transition)
        by_seq = {job.seq: job for job in jobs}
        for t in transitions:
            self._transition = max(self._transition, t.id)
            if t.machine in self.publisher.vars:
                self.publisher.transition(t, by_seq.get(t.seq))
        machines = set()
        for job in jobs:
            self._rev = max(self._rev, job.rev)
            if job.machine in self.publisher.vars:
                self.publisher.job(job)
                machines.add(job.machine)
        for name in sorted(machines):
            await self._summary(name)

    async def _summary(self, machine: str) -> None:
        q = self.queue

        def read() -> dict[str, Any]:
            sending = q.list(machine=machine, states=(JobState.SENDING,), limit=1)
            return {
                "waiting": q.count(machine=machine, states=(JobState.QUEUED, JobState.SENDING)),
                "failed": q.count(machine=machine, states=(JobState.FAILED,)),
                "current": sending[0] if sending else None,
                "delivered": q.latest(machine, JobState.DELIVERED),
                "failed_job": q.latest(machine, JobState.FAILED),
                "rejected": q.latest(machine, JobState.REJECTED),
            }

        self.publisher.summary(machine, **await self.threads.queue(read))
