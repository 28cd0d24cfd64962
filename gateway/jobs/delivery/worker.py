"""Delivery: one worker per machine moves its queue to the controller, through its delivery transport.

Machines deliver in parallel; each machine's jobs go strictly one at a time, in
queue order (priority first, then FIFO), because sheets are cut in sequence.
A failed attempt waits with exponential backoff; after `max_attempts` the job
is FAILED (dead letter) and the next one goes.

Idempotent after a crash. A job found in SENDING when the gateway starts may or
may not have reached the controller: the worker asks the transport whether the
controller holds it already (FTP: the name, the expected size, and the SHA-256
of the program downloaded back). Found: DELIVERED, without sending it again
(and without auto-starting it: nobody can know whether it already ran).
Otherwise what the interrupted delivery left is removed and the job is sent again.

How a program travels is the transport's business (transport.py); this module
knows jobs, attempts, backoff and auto-start, and nothing of FTP.

A program missing from this process's spool (a job another shard's inbox took in) is read from the job
queue's database when the queue carries programs (`fetch`, delivery/fetch.py), checked against the
SHA-256 validation gave it, before it goes.

Shards (docs/scaling.md): given a `lease` (gateway/shards/holder.py), the worker acts only while
its process holds the machine's lease, and presents the lease's fencing token with the claim
and with its outcome, so that the queue refuses a worker whose process lost the machine.
"""

from __future__ import annotations

import asyncio
import logging
import time
from collections.abc import Awaitable, Callable
from pathlib import Path
from typing import Any, Protocol

from gateway.config.jobs import JobsConfig
from gateway.errors import DeliveryError, JobError, JobStoreError
from gateway.jobs.delivery.autostart import AutoStarter
from gateway.jobs.queue.base import JobStore
from gateway.jobs.queue.publish import JobPublisher
from gateway.jobs.queue.records import Job, JobState
from gateway.shards.fence import Fence
from gateway.transports.base import DeliveryTransport, Program, Progress

log = logging.getLogger("gateway.jobs.delivery")

IDLE_POLL = 5.0  # s: a worker with nothing to do looks again at least this often
LEASE_POLL = 1.0  # s: a worker whose process does not hold its machine's lease looks again this often


def progress_record(progress: Progress) -> dict[str, Any]:
    """A transport's progress as the job's record shows it (`jobs/<id>` on MQTT, `cnc-gateway jobs`)."""
    record: dict[str, Any] = {"sent": progress.sent}
    if progress.block is not None or progress.lead is not None:  # a drip-feed says more
        record["block"] = progress.block
        record["lead"] = None if progress.lead is None else round(progress.lead, 1)
        record["remaining"] = None if progress.remaining is None else round(progress.remaining, 1)
        record["held"] = progress.held
    return record


class Spool(Protocol):
    def program(self, job: Job) -> Path: ...

    def discard(self, job: Job) -> None: ...

    def delivered(self, job: Job) -> None: ...


class LeaseView(Protocol):
    """The machines' leases as a worker sees them (gateway/shards/holder.py `LeaseHolder`)."""

    def fence(self, machine: str) -> Fence | None: ...


# Writes a job's stored program to a path, checked (delivery/fetch.py ProgramFetch); raises DeliveryError.
FetchProgram = Callable[[Job, Path], Awaitable[None]]

# Runs a JobStore method off the event loop (and tells the publisher something may have changed).
QueueCall = Callable[..., Awaitable[Any]]


class DeliveryWorker:
    """Delivers one machine's jobs. `wake()` when its queue may have changed."""

    def __init__(
        self,
        machine: str,
        config: JobsConfig,
        queue: JobStore,
        spool: Spool,
        publisher: JobPublisher,
        run: QueueCall,
        transport: DeliveryTransport,
        *,
        autostart: AutoStarter | None = None,
        lease: LeaseView | None = None,
        fetch: FetchProgram | None = None,
    ) -> None:
        self.machine = machine
        self.config = config
        self.queue = queue
        self.spool = spool
        self.publisher = publisher
        self._q = run
        self.transport = transport
        self.autostart = autostart
        self.lease = lease  # None: this process owns the machine (no shards)
        self.fetch = fetch  # None: programs are only in the spool (the SQLite queue)
        self._wake = asyncio.Event()

    def wake(self) -> None:
        self._wake.set()

    async def _sleep(self, seconds: float) -> None:
        try:  # asyncio.timeout, not wait_for, which can swallow a cancellation in Python 3.11
            async with asyncio.timeout(min(seconds, IDLE_POLL)):
                await self._wake.wait()
        except TimeoutError:
            pass
        self._wake.clear()

    async def run(self) -> None:
        """Until cancelled: take the head of the queue, deliver it (or re-check it after a crash)."""
        task = asyncio.current_task()
        while True:
            # A cancellation that something on the delivery path swallowed (seen: a worker back in its idle
            # sleep while "cancelling", holding up the gateway's shutdown until the test's timeout) still
            # ends the worker at its next turn.
            if task is not None and task.cancelling():
                raise asyncio.CancelledError
            fence = self.lease.fence(self.machine) if self.lease is not None else None
            if self.lease is not None and fence is None:  # another shard's machine, for now
                await self._sleep(LEASE_POLL)
                continue
            try:
                job: Job | None = await self._q(self.queue.head, self.machine)
            except JobStoreError as exc:  # the queue's database is away (PostgreSQL): wait for it
                log.warning(
                    "%s: the job queue cannot be read (%s); again in %g s", self.machine, exc, LEASE_POLL
                )
                await self._sleep(LEASE_POLL)
                continue
            if job is None:
                await self._sleep(IDLE_POLL)
                continue
            if job.state is JobState.SENDING:
                await self._fenced(self.recover(job, fence), job)
                continue
            wait = (job.next_attempt_at or 0.0) - time.time()
            if wait > 0:
                await self._sleep(wait)
                continue
            await self._fenced(self.deliver(job, fence), job)

    async def _fenced(self, step: Awaitable[None], job: Job) -> None:
        """A step that a lease holder may lose midway (a refusal of its fencing token ends it, logged), or
        that meets a PostgreSQL queue that is away (the job stays where it is; the worker waits)."""
        try:
            await step
        except JobStoreError as exc:
            log.warning("%s: %s waits for the job queue: %s", self.machine, job.id, exc)
            await self._sleep(LEASE_POLL)
        except JobError as exc:
            if self.lease is None:
                raise
            log.warning("%s: %s left to the machine's next holder: %s", self.machine, job.id, exc)

    # --- one job ------------------------------------------------------------------------------------

    def _still_held(self, fence: Fence | None) -> bool:
        """With shards: does this process still hold the lease it claimed with (by its own clock)?"""
        return self.lease is None or self.lease.fence(self.machine) == fence

    async def deliver(self, job: Job, fence: Fence | None = None) -> None:
        try:
            job = await self._q(self.queue.start_sending, job.seq, fence=fence)
        except JobError:  # cancelled or changed from the CLI a moment ago, or the lease is lost
            return
        if not self._still_held(fence):  # the lease may have run out meanwhile: the next holder recovers it
            log.warning("%s: %s claimed, but the lease is no longer sure; leaving it", self.machine, job.id)
            return
        program = self.program(job)
        name, total = program.name, program.size
        started = time.monotonic()
        log.info("%s: sending %s (%s, %d bytes), attempt %d", self.machine, job.id, name, total, job.attempts)
        self.publisher.progress(job, 0, total)

        def report(progress: Progress) -> None:
            self.publisher.progress(job, progress.sent, total, progress_record(progress))

        try:
            if self.fetch is not None and not program.path.is_file():
                await self.fetch(job, program.path)  # taken in by another shard: from the database
            if not program.path.is_file():
                missing = f"the program file {program.path} is missing from the spool"
                raise DeliveryError(missing, permanent=True)
            where = await self.transport.deliver(program, report)
        except DeliveryError as exc:
            await self._failed(job, exc, fence)
            return
        finally:
            self.publisher.forget(job)
        seconds = time.monotonic() - started
        reason = f"delivered to {where} in {seconds:.1f} s"
        try:
            job = await self._q(self.queue.delivered, job.seq, name, reason, fence=fence)
        except JobError as exc:  # the lease was lost while sending: the next holder checks the controller
            log.warning("%s: %s sent, but not recorded: %s", self.machine, job.id, exc)
            return
        log.info("%s: %s delivered as %s", self.machine, job.id, name)
        self.spool.delivered(job)
        if self.autostart is not None:
            outcome = await self.autostart.run(job, name)
            log.info("%s: %s %s", self.machine, job.id, outcome)
            await self._q(self.queue.note, job.seq, f"{job.reason}; {outcome}")

    def program(self, job: Job) -> Program:
        """What the transport needs of a queued job."""
        size, digest = job.program_size or 0, job.program_sha256 or ""
        return Program(job.filename, self.spool.program(job), size, digest, job.program_name, job.user)

    async def _failed(self, job: Job, exc: DeliveryError, fence: Fence | None = None) -> None:
        attempts, limit = job.attempts, self.config.max_attempts
        reason = exc.reason
        if exc.permanent or attempts >= limit:
            why = "" if exc.permanent else f" after {attempts} attempt{'s' if attempts != 1 else ''}"
            await self._q(
                self.queue.send_failed, job.seq, f"failed{why}: {reason}", retry_at=None, fence=fence
            )
            log.warning("%s: %s FAILED%s: %s", self.machine, job.id, why, reason)
            return
        delay = self.config.retry.delay(attempts)
        await self._q(
            self.queue.send_failed,
            job.seq,
            f"attempt {attempts} of {limit} failed: {reason}; next in {delay:g} s",
            retry_at=time.time() + delay,
            fence=fence,
        )
        log.info(
            "%s: %s attempt %d failed (%s); retrying in %g s", self.machine, job.id, attempts, reason, delay
        )

    # --- after a crash ----------------------------------------------------------------------------

    async def recover(self, job: Job, fence: Fence | None = None) -> None:
        """A job left SENDING by an earlier run: delivered after all, or to be sent again?"""
        program = self.program(job)
        attempt = 0
        while True:
            attempt += 1
            try:
                if await self.transport.holds(program):
                    found = "found complete on the controller after a restart"
                    job = await self._q(self.queue.delivered, job.seq, program.name, found, fence=fence)
                    log.info(
                        "%s: %s was delivered before the restart; not sending it again", self.machine, job.id
                    )
                    self.spool.delivered(job)
                    return
                break
            except DeliveryError as exc:
                if exc.permanent:  # the transport says it must not be sent again on its own
                    await self._q(
                        self.queue.send_failed, job.seq, f"failed: {exc.reason}", retry_at=None, fence=fence
                    )
                    log.warning("%s: %s FAILED after a restart: %s", self.machine, job.id, exc.reason)
                    return
                delay = self.config.retry.delay(attempt)
                log.warning(
                    "%s: cannot check %s on the controller (%s); again in %g s",
                    self.machine,
                    job.id,
                    exc.reason,
                    delay,
                )
                await asyncio.sleep(delay)
        await self._q(
            self.queue.send_failed,
            job.seq,
            "interrupted by a restart; sending again",
            retry_at=time.time(),
            fence=fence,
        )
