"""Intake: a complete upload (the FTP inbox, the web console, Programs.Put, a punched request) becomes a
job: stored in the spool, validated, QUEUED or REJECTED with its reason.

Answers the uploader within the inbox's `reply_within`; validation that takes longer goes on, and its
verdict is the job's record. Programs over a size are validated in the validation process.
"""

from __future__ import annotations

import asyncio
import contextlib
import hashlib
import logging
import os
import re
import uuid
from collections.abc import Awaitable, Collection, Mapping
from pathlib import Path
from typing import Any, TypeVar

from gateway.config.jobs import JobsConfig
from gateway.errors import DeliveryError, JobError, PathRefused
from gateway.jobs.delivery.fetch import ProgramFetch
from gateway.jobs.delivery.supervisor import DeliverySupervisor
from gateway.jobs.inbox.inbox import STAGING, Upload, UploadReply
from gateway.jobs.inbox.paths import check_file_name
from gateway.jobs.queue.base import JobStore
from gateway.jobs.queue.store import Job, JobState
from gateway.jobs.spool import Spool
from gateway.jobs.threads import JobThreads
from gateway.jobs.validation.file_check import ISOLATE_ABOVE, Checked, link_durably, validate_file
from gateway.jobs.validation.upload_check import UploadCheck
from gateway.jobs.validation.verdict import Verdict
from gateway.transports.base import QueuedProgram

log = logging.getLogger("gateway.jobs")

T = TypeVar("T")


def summarize(verdict: Verdict) -> str:
    """One line for the FTP reply and the job's reason: the first rejection and how many more."""
    first = verdict.rejections[0]  # the validator's reasons say where: "line 12, column 3: …"
    more = len(verdict.rejections) - 1
    return first.reason + (f" (and {more} more)" if more else "")


class Intake:
    """Takes uploads in for the machines of `machines` (those with a `jobs:` section): this process's, and
    on a queue that carries programs (PostgreSQL) the fleet's machines other shards serve, whose jobs are
    validated here by their own rules and delivered by their shard (`serves`: this process's machines)."""

    def __init__(
        self,
        machines: Mapping[str, JobsConfig],
        *,
        serves: Collection[str] | None = None,
        queue: JobStore,
        spool: Spool,
        threads: JobThreads,
        supervisor: DeliverySupervisor,
        state_dir: Path,
        reply_within: float,
        by_lease: bool = False,
    ) -> None:
        """`by_lease` (`shard: lease`): whichever shard holds a machine when its job's turn comes delivers it,
        so the spool keeps no copy of a queued program: every delivery reads it from the queue's database
        (a copy kept here would stay behind whenever another shard delivered the job)."""
        self.machines = machines
        self.serves = frozenset(machines if serves is None else serves)
        self.by_lease = by_lease
        self.queue = queue
        self.spool = spool
        self.threads = threads
        self.supervisor = supervisor
        self.rejected_dir = state_dir / "rejected"
        self.inbox_root = state_dir / "inbox"
        self.reply_within = reply_within
        self.tasks: set[asyncio.Task[Any]] = set()
        # Where the queue carries programs, one this spool lacks is read back from it (for requests).
        self.fetch = ProgramFetch(queue, threads.work) if queue.shares_programs else None

    def _spawn(self, coro: Awaitable[T], name: str) -> asyncio.Task[T]:
        task: asyncio.Task[T] = asyncio.ensure_future(coro)
        task.set_name(name)
        self.tasks.add(task)
        task.add_done_callback(self.tasks.discard)
        return task

    async def cancel(self) -> None:
        """Stop what is being taken in (the service is stopping)."""
        tasks = list(self.tasks)
        for task in tasks:
            task.cancel()
        if tasks:
            await asyncio.wait(tasks)

    async def submit(self, upload: Upload) -> UploadReply:
        """A complete upload (the service now owns `upload.path`). Answers within `reply_within` seconds."""
        if upload.machine not in self.machines:
            upload.path.unlink(missing_ok=True)
            return UploadReply(False, f"{upload.machine} takes no jobs")
        holder: dict[str, Job] = {}
        task = self._spawn(self._take(upload, holder), f"jobs:take:{upload.machine}")
        try:
            async with asyncio.timeout(self.reply_within):
                return await asyncio.shield(task)
        except TimeoutError:
            job = holder.get("job")
            if job is None:
                return UploadReply(True, "received; still being stored")
            return UploadReply(
                True, f"{job.id} received; validation continues (cnc-gateway jobs show {job.id})", job.id
            )

    async def submit_bytes(
        self, machine: str, filename: str, data: bytes, *, user: str, origin: str
    ) -> UploadReply:
        """A program that comes other than through the inbox (Programs.Put): the same checks and queue."""
        try:
            check_file_name(filename)
        except PathRefused as exc:
            return UploadReply(False, exc.reason)
        staging = self.inbox_root / STAGING / uuid.uuid4().hex
        staging.parent.mkdir(parents=True, exist_ok=True)
        await self.threads.work(staging.write_bytes, data)
        upload = Upload(machine, filename, staging, len(data), hashlib.sha256(data).hexdigest(), user, origin)
        return await self.submit(upload)

    async def submit_request(self, machine: str, filename: str, data: bytes, user: str, origin: str) -> str:
        """A remote request answered through the queue (punch.requests.send: queue)."""
        reply = await self.submit_bytes(machine, filename, data, user=user, origin=origin)
        return reply.message

    async def find_requested(self, machine: str, name: str) -> QueuedProgram | None:
        """The newest accepted job of `machine` that a remote request for `name` names, with its validated
        program (read from the spool, checked against the SHA-256 validation gave it); None if none."""
        jobs = await self.threads.queue(
            self.queue.list, machine=machine, states=REQUESTABLE, limit=REQUEST_SCAN
        )
        for job in jobs:
            if not matches(job, name):
                continue
            data = await self.threads.work(self._spooled, job)
            if data is None and self.fetch is not None and job.state is not JobState.DELIVERED:
                data = await self._from_queue(job)  # another shard took it in
            if data is not None:
                return QueuedProgram(data, job.filename, job.user, job.id)
        return None

    async def _from_queue(self, job: Job) -> bytes | None:
        """A job's program read back (checked) from the queue's database into the spool, for a request."""
        assert self.fetch is not None
        try:
            await self.fetch(job, self.spool.program(job))
        except DeliveryError as exc:
            log.warning("%s: %s's program cannot be read for a request: %s", job.machine, job.id, exc.reason)
            return None
        return await self.threads.work(self._spooled, job)

    def _spooled(self, job: Job) -> bytes | None:
        for path in (self.spool.program(job), self.spool.kept(job)):
            try:
                data = path.read_bytes()
            except FileNotFoundError:
                continue
            except OSError as exc:
                log.warning("%s: %s's program unreadable for a request: %s", job.machine, job.id, exc)
                return None
            if job.program_sha256 and hashlib.sha256(data).hexdigest() != job.program_sha256:
                log.warning(
                    "%s: %s's program %s is not the one validated; not sent", job.machine, job.id, path
                )
                return None
            return data
        return None

    async def _take(self, upload: Upload, holder: dict[str, Job]) -> UploadReply:
        processing = self.supervisor.processing
        processing[upload.machine] = processing.get(upload.machine, 0) + 1
        try:
            try:
                job = await self.supervisor.q(
                    self.queue.receive,
                    upload.machine,
                    upload.filename,
                    upload.size,
                    upload.sha256,
                    user=upload.user,
                    origin=upload.client,
                    priority=upload.priority,
                )
            except BaseException:
                upload.path.unlink(missing_ok=True)
                raise
            await self.threads.work(os.replace, upload.path, self.spool.received(job))
            holder["job"] = job
            log.info(
                "%s: %s received %s (%d bytes) from %s@%s",
                job.machine,
                job.id,
                job.filename,
                job.size,
                upload.user,
                upload.client,
            )
            return await self._process(job, upload.check)
        finally:
            processing[upload.machine] -= 1

    async def _process(self, job: Job, check: UploadCheck | None = None) -> UploadReply:
        """RECEIVED -> validated and QUEUED, or REJECTED with the reason (the file kept in rejected/)."""
        try:
            return await self._validate_and_queue(job, check)
        except asyncio.CancelledError:
            raise
        except Exception as exc:
            log.exception("%s: %s could not be processed", job.machine, job.id)
            with contextlib.suppress(JobError):
                await self.supervisor.q(
                    self.queue.reject, job.seq, f"internal error while checking the program: {exc}"
                )
            return UploadReply(False, f"{job.id} could not be processed: {exc}", job.id)

    async def _validate_and_queue(self, job: Job, check: UploadCheck | None = None) -> UploadReply:
        rules = self.machines[job.machine].validation
        received = self.spool.received(job)
        checked = await self._checked_on_arrival(job, check) if check is not None else None
        if checked is None:
            # Large programs in the validation process: seconds of CPU in a thread would stall the event loop.
            run = self.threads.process if job.size > ISOLATE_ABOVE else self.threads.work
            checked = await run(
                validate_file, received, self.spool.program(job), job.filename, rules, job.sha256
            )
        verdict = checked.verdict
        if not verdict.accepted:
            reason = summarize(verdict)
            await self.threads.work(self._keep_rejected, job, verdict)
            job = await self.supervisor.q(self.queue.reject, job.seq, reason)
            log.warning("%s: %s (%s) rejected: %s", job.machine, job.id, job.filename, reason)
            return UploadReply(False, f"{job.id} rejected: {reason}", job.id)
        received.unlink(missing_ok=True)
        program = self.spool.program(job)
        job, replaced = await self.supervisor.q(
            self.queue.accept,
            job.seq,
            duplicates=self.machines[job.machine].duplicates,
            program_size=checked.size,
            program_sha256=checked.sha256,
            program_name=verdict.program_name,
            estimate=verdict.estimate.as_dict() if verdict.estimate is not None else None,
            warnings=verdict.warnings,
            reason=_validated_reason(verdict),
            program=program,  # stored with the job where the queue carries programs (PostgreSQL)
        )
        for old in replaced:
            log.info("%s: %s replaced by %s (same content)", job.machine, old.id, job.id)
        if job.state is JobState.REJECTED:
            self.spool.discard(job)
            log.info("%s: %s skipped: %s", job.machine, job.id, job.reason)
            return UploadReply(True, f"{job.id} skipped: {job.reason}", job.id)
        if self.by_lease or job.machine not in self.serves:  # delivered from the queue's copy
            await self.threads.work(self.spool.discard, job)
        self.supervisor.wake(job.machine)
        seconds = (job.estimate or {}).get("seconds")
        estimate = f", estimated {seconds:.0f} s" if isinstance(seconds, (int, float)) else ""
        log.info("%s: %s queued (%s%s)", job.machine, job.id, job.filename, estimate)
        return UploadReply(True, f"{job.id} queued for {job.machine}{estimate}", job.id)

    async def _checked_on_arrival(self, job: Job, check: UploadCheck) -> Checked | None:
        """The verdict of the check made as the upload arrived, the program stored; None to validate anew
        (the check failed, or the program to deliver differs from the upload)."""
        try:
            verdict = await check.verdict(job.filename)
        except Exception:
            log.exception(
                "%s: %s: the check on arrival failed; validating the stored upload", job.machine, job.id
            )
            return None
        if check.changed:
            return None  # XON/XOFF bytes to strip: validate_file writes the program without them
        if verdict.accepted and not await self.threads.work(
            link_durably, self.spool.received(job), self.spool.program(job)
        ):
            return None
        size, digest = (job.size, job.sha256) if verdict.accepted else (0, "")
        return Checked(verdict, size, digest, os.getpid())

    def _keep_rejected(self, job: Job, verdict: Verdict) -> None:
        target = self.rejected_dir / f"{job.id}-{job.filename}"
        os.replace(self.spool.received(job), target)
        lines = [
            f"job: {job.id}",
            f"machine: {job.machine}",
            f"file: {job.filename}",
            f"from: {job.user}@{job.origin}",
            f"received: {job.received_at.isoformat()}",
            f"size: {job.size} bytes, sha256 {job.sha256}",
            "rejected because:",
        ]
        lines.extend(f"  [{r.rule}] {r.reason}" for r in verdict.rejections)
        if verdict.warnings:
            lines.append("warnings:")
            lines.extend(f"  {w}" for w in verdict.warnings)
        Path(f"{target}.reason").write_text("\n".join(lines) + "\n", encoding="utf-8")

    async def resume(self) -> None:
        """Jobs an earlier run left between arrival and the queue: finish them, or reject lost ones."""
        # This intake's uploads, not other shards' (on a shared queue).
        for job in await self.threads.queue(self.queue.received_here, sorted(self.serves)):
            if job.machine not in self.machines:
                continue
            if self.spool.received(job).is_file():
                log.info("%s: resuming %s (received before the restart)", job.machine, job.id)
                self._spawn(self._process(job), f"jobs:resume:{job.id}")
            else:
                await self.supervisor.q(
                    self.queue.reject, job.seq, "the upload was lost when the gateway stopped; send it again"
                )


def matches(job: Job, name: str) -> bool:
    """Does a remote request for `name` name this job: its file name (with or without its extension), or
    its program's own name (the O-number, O4711 = O04711)?"""
    wanted = name.upper()
    filename = job.filename.upper()
    if wanted in (filename, filename.rsplit(".", 1)[0]):
        return True
    own = (job.program_name or "").upper()
    if own and own == wanted:
        return True
    a, b = _O_NUMBER.fullmatch(wanted), _O_NUMBER.fullmatch(own)
    return a is not None and b is not None and int(a.group(1)) == int(b.group(1))


_O_NUMBER = re.compile(r"O0*(\d+)")
# Accepted jobs whose program a remote request may name: not rejected, not withdrawn (CANCELLED).
REQUESTABLE = (JobState.DELIVERED, JobState.SENDING, JobState.QUEUED, JobState.VALIDATED, JobState.FAILED)
REQUEST_SCAN = 2000  # the newest jobs of a machine looked through for a requested name


def _validated_reason(verdict: Verdict) -> str:
    parts = ["valid"]
    if verdict.estimate is not None and verdict.estimate.seconds is not None:
        parts.append(f"estimated {verdict.estimate.seconds:.1f} s")
    if verdict.warnings:
        parts.append(f"{len(verdict.warnings)} warning{'s' if len(verdict.warnings) != 1 else ''}")
    return ", ".join(parts)
