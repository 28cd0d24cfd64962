"""JobService: inbox -> validation -> durable queue -> delivery, for every machine with `jobs:`.

An async context manager like every long-running part of the gateway. Built
before the sinks start (it adds each machine's `Jobs/...` variables and its
`Programs` methods to the tree, which the sinks then show); entered after the
sinks and sources; `run()` runs one delivery worker per machine and a watcher
that follows the queue file, so that changes made by `cnc-gateway jobs …` from
another process are published and acted upon.

Files under the state directory:

    inbox/<machine>/[tmp/]      the FTP inbox's folders (empty when nothing is uploading)
    jobs/queue.sqlite3          the queue (unless the gateway file's `queue:` names a PostgreSQL database)
    jobs/spool/<id>.received    an upload between arrival and validation
    jobs/spool/<id>.program     a validated program waiting for delivery (kept for FAILED/CANCELLED: retry)
    jobs/spool/delivered/<machine>/<id>.program
                                a delivered job's program, kept for remote requests
                                (punch.requests.from: queue; the newest keep_delivered of the machine)
    rejected/<id>-<name>        a rejected upload, and <id>-<name>.reason saying why
    backups/<machine>/          programs fetched with Programs.Backup (and punched ones, with punch.backup)
    dnc/transfers.sqlite3       the serial transfer log (cnc-gateway dnc log)
    dnc/received/<machine>/     programs operators punched (jobs.punch), each with a .json record
"""

from __future__ import annotations

import asyncio
import contextlib
import functools
import hashlib
import logging
import os
import re
import uuid
from collections.abc import Awaitable, Callable, Mapping, Sequence
from pathlib import Path
from typing import Any, Self, TypeVar

from gateway.auth.ratelimit import LoginLimiter
from gateway.config.jobs import AlarmWhen, ControllerFtp, ControllerSerial, JobsConfig
from gateway.config.loader import Config
from gateway.errors import (
    ConfigError,
    InvalidArgument,
    InvalidState,
    JobError,
    NotFound,
    PathRefused,
    RequestError,
    SinkError,
    StoreError,
)
from gateway.jobs.backups import BackupShelf
from gateway.jobs.delivery.autostart import AutoStarter
from gateway.jobs.delivery.transports import program_store_for, transport_for
from gateway.jobs.delivery.transports.serial import SerialTransport, request_restart
from gateway.jobs.delivery.worker import DeliveryWorker
from gateway.jobs.dnc import control
from gateway.jobs.dnc.desk import PunchDesk, QueuedProgram
from gateway.jobs.dnc.fleet import DripFleet
from gateway.jobs.dnc.received import ReceivedStore
from gateway.jobs.dnc.transfers import TransferLog
from gateway.jobs.drip import drip_methods, line_status
from gateway.jobs.inbox.accounts import Accounts
from gateway.jobs.inbox.inbox import STAGING, Inbox, Upload, UploadReply, tls_context
from gateway.jobs.inbox.paths import check_file_name
from gateway.jobs.programs import program_methods
from gateway.jobs.queue.backend import job_store
from gateway.jobs.queue.base import JobStore
from gateway.jobs.queue.publish import JobPublisher
from gateway.jobs.queue.store import Job, JobState, Transition, parse_job_id
from gateway.jobs.threads import JobThreads
from gateway.jobs.validation import compiled
from gateway.jobs.validation.file_check import ISOLATE_ABOVE, Checked, link_durably, ready, validate_file
from gateway.jobs.validation.upload_check import UploadCheck
from gateway.jobs.validation.verdict import Verdict
from gateway.model.context import WriteContext
from gateway.model.tree import Machine, VariableTree

log = logging.getLogger("gateway.jobs")

T = TypeVar("T")
CONTROL_EVERY = 0.2  # s between looks for drip-feed commands from the shell (jobs pause|resume|abort)
WATCH_INTERVAL = 1.0  # s between looks for changes made by other processes (the CLI)
ENDED_SWEEP = 200  # ended jobs past a machine's retained limit whose records are cleared at start-up


class Spool:
    """Where job files live between arrival and delivery (and after it, for machines that answer remote
    requests from the queue: `keep` delivered programs per machine)."""

    def __init__(self, root: Path, keep: Mapping[str, int] | None = None) -> None:
        self.root = root
        self.keep = dict(keep or {})

    def kept(self, job: Job) -> Path:
        return self.root / "delivered" / job.machine / f"{job.id}.program"

    def delivered(self, job: Job) -> None:
        """The job was delivered: keep its program for remote requests where the machine wants that."""
        keep = self.keep.get(job.machine, 0)
        program = self.program(job)
        if keep <= 0 or not program.is_file():
            self.discard(job)
            return
        folder = self.kept(job).parent
        folder.mkdir(parents=True, exist_ok=True)
        os.replace(program, self.kept(job))
        self.received(job).unlink(missing_ok=True)
        kept = sorted(folder.glob("J*.program"), key=lambda p: _kept_seq(p.stem))
        for old in kept[: max(0, len(kept) - keep)]:
            old.unlink(missing_ok=True)

    def received(self, job: Job) -> Path:
        return self.root / f"{job.id}.received"

    def program(self, job: Job) -> Path:
        return self.root / f"{job.id}.program"

    def discard(self, job: Job) -> None:
        self.received(job).unlink(missing_ok=True)
        self.program(job).unlink(missing_ok=True)


def queue_path(state_dir: Path) -> Path:
    return state_dir / "jobs" / "queue.sqlite3"


def summarize(verdict: Verdict) -> str:
    """One line for the FTP reply and the job's reason: the first rejection and how many more."""
    first = verdict.rejections[0]  # the validator's reasons say where: "line 12, column 3: …"
    more = len(verdict.rejections) - 1
    return first.reason + (f" (and {more} more)" if more else "")


class JobService:
    """The job queue of every machine that has a `jobs:` section."""

    def __init__(
        self,
        config: Config,
        tree: VariableTree,
        *,
        environ: Mapping[str, str] | None = None,
        logins: LoginLimiter | None = None,
    ) -> None:
        self.config = config
        self.tree = tree
        self.environ = environ
        # The gateway's failed-login lockout, shared with its other doors; on its own, one of its own.
        self.logins = logins if logins is not None else config.gateway.login_limiter()
        self.machines: dict[str, JobsConfig] = {
            m.machine: m.jobs for m in config.machines if m.jobs is not None
        }
        state = config.state_dir
        keep = {
            name: jobs.punch.requests.keep_delivered
            for name, jobs in self.machines.items()
            if jobs.punch is not None
            and jobs.punch.requests is not None
            and "queue" in jobs.punch.requests.sources
        }
        self.spool = Spool(state / "jobs" / "spool", keep)
        self.rejected_dir = state / "rejected"
        self.backups_dir = state / "backups"
        self.inbox_root = state / "inbox"
        self.queue: JobStore = job_store(config.gateway.queue, state)  # gateway file's `queue:`, else SQLite
        self.threads = JobThreads()
        self.publisher = JobPublisher(tree, self.machines)
        self.autostarters: dict[str, AutoStarter] = {}
        self.workers: dict[str, DeliveryWorker] = {}
        self.lines: dict[str, SerialTransport] = {}  # the serial DNC lines, by machine
        self.shelves: dict[str, BackupShelf] = {}  # Programs.Backup's copies, by machine
        self.transfer_log: TransferLog | None = None  # opened with the queue when there are serial lines
        # One scheduler for every drip-feed: lines that share a device server share its capacity.
        fleet = DripFleet.for_lines(
            (name, jobs.controller)
            for name, jobs in self.machines.items()
            if isinstance(jobs.controller, ControllerSerial)
        )
        for name, jobs in self.machines.items():
            machine = tree.machines[name]
            if jobs.auto is not None:
                folder = jobs.controller.folder if isinstance(jobs.controller, ControllerFtp) else ""
                self.autostarters[name] = AutoStarter(machine, jobs.auto, folder)
            transport = transport_for(jobs, machine=name, state_dir=state)
            self.workers[name] = DeliveryWorker(
                name,
                jobs,
                self.queue,
                self.spool,
                self.publisher,
                self._q,
                transport,
                autostart=self.autostarters.get(name),
            )
            if isinstance(transport, SerialTransport):
                self.lines[name] = transport
                transport.fleet = fleet
                transport.alarm = alarm_reader(machine, transport.settings.alarm_when)
                transport.on_figures = line_status(machine)
                for method in drip_methods(transport, functools.partial(self.restart_job, machine=name)):
                    machine.add_method(method)
            shelf = self.shelves[name] = BackupShelf(self.backups_dir / name, jobs.backups)
            methods = program_methods(
                name, store=program_store_for(jobs), submit=self.submit_bytes, backups=shelf
            )
            for method in methods:
                machine.add_method(method)
        # Serial lines: what an idle line hears (jobs.punch); the line owner takes its machine's desk.
        self.desks: dict[str, PunchDesk] = {
            name: PunchDesk(
                tree.machines[name],
                jobs.punch,
                store=ReceivedStore(state),
                rules=jobs.validation,
                backups=self.backups_dir / name,
                submit=self._submit_request,
                find_job=self.find_requested,
                blocking=self.threads.work,
            )
            for name, jobs in self.machines.items()
            if jobs.punch is not None
        }
        for name, desk in self.desks.items():
            line = self.lines.get(name)
            if line is not None:
                line.listener = desk  # the line listens for it between jobs
                desk.send_answer = line.send_answer
        self.inbox: Inbox | None = None
        self._changed = asyncio.Event()
        self._tasks: set[asyncio.Task[Any]] = set()
        self._processing: dict[str, int] = dict.fromkeys(self.machines, 0)
        self._rev = 0
        self._transition = 0
        self._opened = False

    # --- lifecycle ---------------------------------------------------------------------------------

    async def __aenter__(self) -> Self:
        for folder in (self.spool.root, self.rejected_dir, self.backups_dir):
            folder.mkdir(parents=True, exist_ok=True)
        try:
            await self.threads.queue(self.queue.open)
        except JobError as exc:
            raise SinkError(str(exc)) from None
        self._opened = True
        try:
            if self.lines or self.desks:
                try:
                    log_file = await self.threads.queue(TransferLog.in_state_dir, self.config.state_dir)
                except StoreError as exc:
                    raise SinkError(str(exc)) from None
                self.transfer_log = log_file
                for line in self.lines.values():
                    line.transfer_log = self.transfer_log
                for desk in self.desks.values():
                    desk.transfers = self.transfer_log
            await self._publish_all()
            await self._resume()
            self.inbox = self._build_inbox()
            if self.inbox is not None:
                await self.inbox.__aenter__()
        except BaseException:
            await self.__aexit__(None, None, None)
            raise
        return self

    async def __aexit__(self, *exc_info: object) -> None:
        inbox, self.inbox = self.inbox, None
        if inbox is not None:
            await inbox.__aexit__(None, None, None)
        tasks = list(self._tasks)
        for task in tasks:
            task.cancel()
        if tasks:
            await asyncio.wait(tasks)
        for line in self.lines.values():
            line.close()
        if self._opened:
            self._opened = False
            for desk in self.desks.values():
                await desk.drain()
            await self.threads.queue(self.queue.close)
            if self.transfer_log is not None:
                await self.threads.queue(self.transfer_log.close)
                self.transfer_log = None
        await self.threads.shutdown()

    def _build_inbox(self) -> Inbox | None:
        cfg = self.config.gateway.inbox
        if not cfg.enabled:
            log.info(
                "the FTP inbox is disabled (inbox.enabled: false); jobs arrive only through Programs.Put"
            )
            return None
        try:
            accounts = Accounts.from_config(cfg, self.machines, self.environ)
        except ConfigError as exc:
            raise SinkError(f"FTP inbox: {exc}") from None
        if not len(accounts):
            log.warning("the FTP inbox is not started: the gateway file's inbox section has no accounts")
            return None
        tls = tls_context(self.config.state_dir, cfg.tls.cert, cfg.tls.key) if cfg.tls is not None else None
        return Inbox(
            cfg,
            root=self.inbox_root,
            machines=self.machines,
            accounts=accounts,
            logins=self.logins,
            submit=self.submit,
            tls=tls,
            jobs_coming=functools.partial(self.threads.warm, ready),
            check_upload=self._upload_check,
        )

    def _upload_check(self, machine: str) -> UploadCheck | None:
        """A check for an upload as it streams in; None where the reader is pure Python (it would hold the
        GIL for seconds: the validation process does that work instead)."""
        if compiled.plain is None or machine not in self.machines:
            return None
        return UploadCheck(self.machines[machine].validation, self.threads.checking)

    async def run(self) -> None:
        """Deliver and publish until cancelled."""
        async with asyncio.TaskGroup() as tg:
            for name, worker in self.workers.items():
                tg.create_task(worker.run(), name=f"jobs:deliver:{name}")
            tg.create_task(self._watch(), name="jobs:watch")
            for name, desk in self.desks.items():
                tg.create_task(desk.run(), name=f"jobs:punch:{name}")
            for name, line in self.lines.items():
                tg.create_task(line.run(), name=f"jobs:dnc-line:{name}")
            if self.lines:
                tg.create_task(self._shell_commands(), name="jobs:dnc-control")

    async def _shell_commands(self) -> None:
        """`cnc-gateway jobs pause|resume|abort MACHINE` (gateway/jobs/dnc/control.py), until cancelled.
        Nothing is taken from a control folder that is not the gateway's own; why is logged once."""
        state = self.config.state_dir
        try:
            await asyncio.to_thread(control.make_control_dir, state)
        except OSError as exc:
            log.warning("cannot make %s: %s", control.control_dir(state), exc.strerror or exc)
        said: str | None = None
        while True:
            problem = await asyncio.to_thread(control.folder_problem, state)
            if problem != said:
                if problem is not None:
                    log.error("drip-feed commands from the shell (jobs pause|resume|abort) are refused: %s",
                              problem)  # fmt: skip
                else:
                    log.info("drip-feed commands from the shell are taken again: %s is the gateway's own",
                             control.control_dir(state))  # fmt: skip
                said = problem
            for request in await asyncio.to_thread(control.take_requests, state):
                reply = await self.shell_command(request)
                try:
                    await asyncio.to_thread(control.answer, request, reply)
                except OSError as exc:
                    log.warning("%s: cannot answer %s: %s", request.machine, request.path.name, exc)
            await asyncio.sleep(CONTROL_EVERY)

    async def shell_command(self, request: control.ControlRequest) -> control.ControlReply:
        """One drip-feed command from the shell, as a method call of origin `cli` (role checked, audited)."""
        machine = self.tree.machines.get(request.machine)
        method = None if machine is None else machine.methods.get(("Commands", request.method))
        if machine is None or method is None:
            return control.ControlReply("BadNotFound", f"{request.machine} has no serial line here")
        try:
            result = await machine.call_method(method, [], WriteContext("cli", request.user, method.role))
        except RequestError as exc:
            return control.ControlReply(exc.status, exc.reason)
        log.info("%s: %s from the shell by %s: %s", request.machine, request.method, request.user, result[0])
        return control.ControlReply("Good", str(result[0]))

    # --- arrivals ----------------------------------------------------------------------------------

    async def submit(self, upload: Upload) -> UploadReply:
        """A complete upload (the service now owns `upload.path`). Answers within `reply_within` seconds."""
        if upload.machine not in self.machines:
            upload.path.unlink(missing_ok=True)
            return UploadReply(False, f"{upload.machine} takes no jobs")
        holder: dict[str, Job] = {}
        task = self._spawn(self._take(upload, holder), f"jobs:take:{upload.machine}")
        try:
            async with asyncio.timeout(self.config.gateway.inbox.reply_within):
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

    async def _submit_request(self, machine: str, filename: str, data: bytes, user: str, origin: str) -> str:
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
            if data is not None:
                return QueuedProgram(data, job.filename, job.user, job.id)
        return None

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
        self._processing[upload.machine] += 1
        try:
            try:
                job = await self._q(
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
            self._processing[upload.machine] -= 1

    async def _process(self, job: Job, check: UploadCheck | None = None) -> UploadReply:
        """RECEIVED -> validated and QUEUED, or REJECTED with the reason (the file kept in rejected/)."""
        try:
            return await self._validate_and_queue(job, check)
        except asyncio.CancelledError:
            raise
        except Exception as exc:
            log.exception("%s: %s could not be processed", job.machine, job.id)
            with contextlib.suppress(JobError):
                await self._q(self.queue.reject, job.seq, f"internal error while checking the program: {exc}")
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
            job = await self._q(self.queue.reject, job.seq, reason)
            log.warning("%s: %s (%s) rejected: %s", job.machine, job.id, job.filename, reason)
            return UploadReply(False, f"{job.id} rejected: {reason}", job.id)
        received.unlink(missing_ok=True)
        job, replaced = await self._q(
            self.queue.accept,
            job.seq,
            duplicates=self.machines[job.machine].duplicates,
            program_size=checked.size,
            program_sha256=checked.sha256,
            program_name=verdict.program_name,
            estimate=verdict.estimate.as_dict() if verdict.estimate is not None else None,
            warnings=verdict.warnings,
            reason=_validated_reason(verdict),
        )
        for old in replaced:
            log.info("%s: %s replaced by %s (same content)", job.machine, old.id, job.id)
        if job.state is JobState.REJECTED:
            self.spool.discard(job)
            log.info("%s: %s skipped: %s", job.machine, job.id, job.reason)
            return UploadReply(True, f"{job.id} skipped: {job.reason}", job.id)
        self.workers[job.machine].wake()
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

    async def _resume(self) -> None:
        """Jobs an earlier run left between arrival and the queue: finish them, or reject lost ones."""
        for job in await self.threads.queue(
            self.queue.list, states=(JobState.RECEIVED,), limit=10_000, newest_first=False
        ):
            if job.machine not in self.machines:
                continue
            if self.spool.received(job).is_file():
                log.info("%s: resuming %s (received before the restart)", job.machine, job.id)
                self._spawn(self._process(job), f"jobs:resume:{job.id}")
            else:
                await self._q(
                    self.queue.reject, job.seq, "the upload was lost when the gateway stopped; send it again"
                )

    # --- the web console's port (gateway/sinks/ports.py JobsPort) -----------------------------------
    # The same staging folder, the same submit() and so the same validation and queue as the FTP inbox.

    @property
    def job_machines(self) -> list[str]:
        return sorted(self.machines)

    @property
    def max_upload(self) -> int:
        return int(self.config.gateway.inbox.max_file_size)

    def staging_file(self) -> Path:
        """A fresh name in the inbox's staging folder (cleared at start-up) for an upload as it arrives."""
        return self.inbox_root / STAGING / uuid.uuid4().hex

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
        return await self.submit(Upload(machine, filename, path, size, sha256, user, origin, priority))

    def _open(self) -> None:
        if not self._opened:
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
        if job.machine not in self.lines:
            raise InvalidArgument(
                f"{job.machine} takes programs over FTP: a restart at a line needs a serial line"
            )
        if job.state is not JobState.FAILED:
            raise InvalidState(f"{job.id} is {job.state.value}: only a FAILED job restarts at a line")
        program = self.spool.program(job)
        if not program.is_file():
            raise InvalidState(f"{job.id}'s program is no longer in the spool")
        await self.threads.work(request_restart, program, line)
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
            job = await self._q(call, seq, arg)
        except JobError as exc:
            raise InvalidState(str(exc)) from None
        worker = self.workers.get(job.machine)
        if worker is not None:
            worker.wake()
        return job.as_dict()

    async def job_counts(self) -> dict[str, dict[str, int]]:
        if not self._opened:
            return {}
        if not self._opened:
            return {}

        def read() -> dict[str, dict[str, int]]:
            return {
                name: {state.value: self.queue.count(machine=name, states=(state,)) for state in JobState}
                for name in self.machines
            }

        return await self.threads.queue(read)

    # --- for the demo ----------------------------------------------------------------------------------

    def machine_busy(self, machine: str) -> bool:
        """True while a job for this machine is on its way or waiting to be started."""
        starter = self.autostarters.get(machine)
        publisher = self.publisher.vars.get(machine)
        waiting = bool(publisher.queue_length.sample.value) if publisher is not None else False
        return waiting or self._processing.get(machine, 0) > 0 or (starter is not None and starter.busy)

    # --- publishing ------------------------------------------------------------------------------------

    def changed(self) -> None:
        """Something in the queue changed: publish it soon."""
        self._changed.set()

    async def _q(self, fn: Callable[..., T], *args: Any, **kwargs: Any) -> T:
        result = await self.threads.queue(fn, *args, **kwargs)
        self.changed()
        return result

    def _spawn(self, coro: Awaitable[T], name: str) -> asyncio.Task[T]:
        task: asyncio.Task[T] = asyncio.ensure_future(coro)
        task.set_name(name)
        self._tasks.add(task)
        task.add_done_callback(self._tasks.discard)
        return task

    async def _watch(self) -> None:
        version = await self.threads.queue(self.queue.data_version)
        while True:
            # asyncio.timeout, not wait_for: Python 3.11's wait_for can swallow a cancellation that
            # arrives as the event fires, and this loop would then never end.
            try:
                async with asyncio.timeout(WATCH_INTERVAL):
                    await self._changed.wait()
            except TimeoutError:
                pass
            self._changed.clear()
            current = await self.threads.queue(self.queue.data_version)
            external = current != version
            version = current
            await self._sync()
            if external:
                for worker in self.workers.values():
                    worker.wake()

    async def _publish_all(self) -> None:
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
            if job.machine in self.machines:
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
            if t.machine in self.machines:
                self.publisher.transition(t, by_seq.get(t.seq))
        machines = set()
        for job in jobs:
            self._rev = max(self._rev, job.rev)
            if job.machine in self.machines:
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


def alarm_reader(machine: Machine, when: AlarmWhen | None) -> Callable[[], str | None] | None:
    """Reads the variable a serial machine's `alarm_when` names (from the line's thread: one attribute
    read); None without one, or when the variable is not mapped (logged)."""
    if when is None:
        return None
    node = machine.nodes.get(when.path)
    if node is None:
        log.warning("%s: alarm_when names %s, which is not mapped: ignored", machine.name, when.path)
        return None

    def read() -> str | None:
        sample = node.sample
        return (
            f"{when.path} = {sample.value!r}" if sample is not None and sample.value == when.equals else None
        )

    return read


def _kept_seq(stem: str) -> int:
    try:
        return parse_job_id(stem)
    except JobError:
        return -1


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


def _seq(job_id: str) -> int:
    try:
        return parse_job_id(job_id)
    except JobError as exc:
        raise NotFound(str(exc)) from None


def _validated_reason(verdict: Verdict) -> str:
    parts = ["valid"]
    if verdict.estimate is not None and verdict.estimate.seconds is not None:
        parts.append(f"estimated {verdict.estimate.seconds:.1f} s")
    if verdict.warnings:
        parts.append(f"{len(verdict.warnings)} warning{'s' if len(verdict.warnings) != 1 else ''}")
    return ", ".join(parts)
