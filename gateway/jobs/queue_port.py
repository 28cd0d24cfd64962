"""The job queue's operations, as one port: what the web console (gateway/sinks/ports.py `JobsPort`), the
machines' `Commands` (a restart at a line) and the gateway's own parts do with jobs once they exist.

The same staging folder, the same intake and so the same validation and queue as the FTP inbox.
"""

from __future__ import annotations

import functools
import uuid
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

from gateway.errors import InvalidArgument, InvalidState, JobError, JobStoreError, NotFound, PathRefused
from gateway.jobs.delivery.supervisor import DeliverySupervisor
from gateway.jobs.inbox.inbox import STAGING, Upload, UploadReply
from gateway.jobs.inbox.paths import check_file_name
from gateway.jobs.intake import Intake
from gateway.jobs.queue.base import JobStore
from gateway.jobs.queue.store import Job, JobState, Transition, parse_job_id
from gateway.jobs.threads import JobThreads


class QueuePort:
    """The queue's operations for the machines with a `jobs:` section. Refuses (InvalidState) until the
    service has opened the queue (`opened`)."""

    def __init__(
        self,
        queue: JobStore,
        threads: JobThreads,
        intake: Intake,
        supervisor: DeliverySupervisor,
        *,
        max_upload: int,
    ) -> None:
        self.queue = queue
        self.spool = intake.spool
        self.threads = threads
        self.intake = intake
        self.supervisor = supervisor
        self.machines = intake.machines
        self._max_upload = max_upload
        self.opened = False

    @property
    def job_machines(self) -> list[str]:
        return sorted(self.machines)

    @property
    def max_upload(self) -> int:
        return self._max_upload

    def staging_file(self) -> Path:
        """A fresh name in the inbox's staging folder (cleared at start-up) for an upload as it arrives."""
        return self.intake.inbox_root / STAGING / uuid.uuid4().hex

    async def submit_file(
        self,
        machine: str,
        filename: str,
        path: Path,
        *,
        size: int,
        sha256: str,
        user: str,
        origin: str,
        priority: int = 0,
    ) -> UploadReply:
        """A program uploaded other than through FTP (the web console), already in a staging file."""
        try:
            check_file_name(filename)
        except PathRefused as exc:
            await self.threads.work(functools.partial(path.unlink, missing_ok=True))
            return UploadReply(False, exc.reason)
        return await self.intake.submit(Upload(machine, filename, path, size, sha256, user, origin, priority))

    def _open(self) -> None:
        if not self.opened:
            raise InvalidState("the job queue is not open yet (the gateway is starting)")

    async def list_jobs(
        self, *, machine: str | None, states: Sequence[str], limit: int
    ) -> list[dict[str, Any]]:
        self._open()
        try:
            wanted = tuple(JobState(s.upper()) for s in states)
        except ValueError:
            raise InvalidArgument(
                f"states are {', '.join(s.value for s in JobState)}; got {', '.join(states)}"
            ) from None
        jobs = await self.threads.queue(self.queue.list, machine=machine, states=wanted, limit=limit)
        return [job.as_dict() for job in jobs]

    async def show_job(self, job_id: str) -> dict[str, Any]:
        self._open()
        seq = _seq(job_id)

        def read() -> tuple[Job, list[Transition]]:
            return self.queue.get(seq), self.queue.history(seq)

        try:
            job, history = await self.threads.queue(read)
        except JobError as exc:
            raise NotFound(str(exc)) from None
        record = job.as_dict()
        record["history"] = [
            {
                "state": t.state.value,
                "previous": t.previous.value if t.previous else None,
                "reason": t.reason,
                "ts": t.ts.isoformat(),
            }
            for t in history
        ]
        return record

    async def retry_job(self, job_id: str, by: str) -> dict[str, Any]:
        return await self._operate(self.queue.retry, job_id, by)

    async def restart_job(
        self, job_id: str, line: int, by: str, *, machine: str | None = None
    ) -> dict[str, Any]:
        """A FAILED drip-feed queued again, to start at program line `line` (header, modal state, line on)."""
        self._open()
        seq = _seq(job_id)
        try:
            job = await self.threads.queue(self.queue.get, seq)
        except JobError as exc:
            raise NotFound(str(exc)) from None
        if machine is not None and job.machine != machine:
            raise InvalidArgument(f"{job.id} is a job of {job.machine}, not {machine}")
        delivery = self.supervisor.deliveries.get(job.machine)
        restart_at = None if delivery is None else delivery.restart_at
        if restart_at is None:
            raise InvalidArgument(
                f"{job.machine} takes programs over FTP: a restart at a line needs a serial line"
            )
        if job.state is not JobState.FAILED:
            raise InvalidState(f"{job.id} is {job.state.value}: only a FAILED job restarts at a line")
        program = self.spool.program(job)
        if not program.is_file():
            raise InvalidState(f"{job.id}'s program is no longer in the spool")
        await self.threads.work(restart_at, program, line)
        return await self._operate(self.queue.retry, job_id, f"{by} (restart at line {line})")

    async def cancel_job(self, job_id: str, by: str) -> dict[str, Any]:
        return await self._operate(self.queue.cancel, job_id, by)

    async def prioritize_job(self, job_id: str, priority: int) -> dict[str, Any]:
        return await self._operate(self.queue.set_priority, job_id, priority)

    async def _operate(self, call: Callable[..., Job], job_id: str, arg: Any) -> dict[str, Any]:
        self._open()
        seq = _seq(job_id)
        try:
            await self.threads.queue(self.queue.get, seq)
        except JobError as exc:
            raise NotFound(str(exc)) from None
        try:
            job = await self.supervisor.q(call, seq, arg)
        except JobError as exc:
            raise InvalidState(str(exc)) from None
        self.supervisor.wake(job.machine)
        return job.as_dict()

    async def job_counts(self) -> dict[str, dict[str, int]]:
        """Jobs per machine and state (/metrics); none while the queue's database cannot be read, so that a
        scrape during a database restart still has every other figure."""
        if not self.opened:
            return {}

        def read() -> dict[str, dict[str, int]]:
            return {
                name: {state.value: self.queue.count(machine=name, states=(state,)) for state in JobState}
                for name in self.machines
            }

        try:
            return await self.threads.queue(read)
        except JobStoreError:  # the delivery side says once that the queue is away, and when it is back
            return {}


def _seq(job_id: str) -> int:
    try:
        return parse_job_id(job_id)
    except JobError as exc:
        raise NotFound(str(exc)) from None
