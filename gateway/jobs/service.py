"""JobService: inbox -> validation -> durable queue -> delivery, for every machine with `jobs:`.

An async context manager like every long-running part of the gateway. Built
before the sinks start (it adds each machine's `Jobs/...` variables and its
`Programs` methods to the tree, which the sinks then show); entered after the
sinks and sources. It assembles three parts and the machines: the intake
(intake.py: an upload becomes a job), the queue's operations as one port
(queue_port.py: the web console's `JobsPort`), and the delivery supervisor
(delivery/supervisor.py: `run()` runs one delivery worker per machine, what the
transports run besides, and a watcher that follows the queue file, so that
changes made by `cnc-gateway jobs …` from another process are published and
acted upon); assembly.py builds each machine's delivery through its transport's
spec.

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

import contextlib
import functools
import logging
from collections.abc import Mapping
from typing import Self

from gateway.auth.ratelimit import LoginLimiter
from gateway.config.jobs import JobsConfig
from gateway.config.loader import Config
from gateway.errors import ConfigError, JobError, SinkError
from gateway.jobs.assembly import assemble_machines
from gateway.jobs.delivery.supervisor import DeliverySupervisor
from gateway.jobs.delivery.worker import LeaseView
from gateway.jobs.inbox.accounts import Accounts
from gateway.jobs.inbox.inbox import Inbox, tls_context
from gateway.jobs.intake import Intake
from gateway.jobs.queue.backend import job_store
from gateway.jobs.queue.base import JobStore
from gateway.jobs.queue.publish import JobPublisher
from gateway.jobs.queue_port import QueuePort
from gateway.jobs.spool import Spool
from gateway.jobs.threads import JobThreads
from gateway.jobs.validation import compiled
from gateway.jobs.validation.file_check import ready
from gateway.jobs.validation.upload_check import UploadCheck
from gateway.model.tree import VariableTree

log = logging.getLogger("gateway.jobs")


class JobService:
    """The job queue of every machine that has a `jobs:` section."""

    def __init__(
        self,
        config: Config,
        tree: VariableTree,
        *,
        environ: Mapping[str, str] | None = None,
        logins: LoginLimiter | None = None,
        lease: LeaseView | None = None,
    ) -> None:
        """`lease`: with `shard: lease`, each machine's jobs are delivered only while it is held here."""
        self.config = config
        self.tree = tree
        self.environ = environ
        # The gateway's failed-login lockout, shared with its other doors; on its own, one of its own.
        self.logins = logins if logins is not None else config.gateway.login_limiter()
        self.machines: dict[str, JobsConfig] = {
            m.machine: m.jobs for m in config.machines if m.jobs is not None
        }
        state = config.state_dir
        self.spool = Spool(state / "jobs" / "spool")  # what it keeps per machine: the machine's transport
        self.backups_dir = state / "backups"
        self.queue: JobStore = job_store(config.gateway.queue, state)  # gateway file's `queue:`, else SQLite
        # A shard's inbox takes jobs for the fleet's other machines too when the queue carries programs
        # (PostgreSQL): their shard delivers them. On a SQLite queue it refuses them, saying where they go.
        self.elsewhere = dict(config.jobs_elsewhere)
        self.accepts: dict[str, JobsConfig] = {
            **(self.elsewhere if self.queue.shares_programs else {}),
            **self.machines,
        }
        self.threads = JobThreads()
        self.delivery = DeliverySupervisor(self.queue, self.threads, JobPublisher(tree, self.machines))
        self.intake = Intake(
            self.accepts,
            serves=self.machines,
            queue=self.queue,
            spool=self.spool,
            threads=self.threads,
            supervisor=self.delivery,
            state_dir=state,
            reply_within=config.gateway.inbox.reply_within,
            by_lease=lease is not None,
        )
        self.port = QueuePort(
            self.queue,
            self.threads,
            self.intake,
            self.delivery,
            max_upload=int(config.gateway.inbox.max_file_size),
        )
        self.shelves = assemble_machines(  # Programs.Backup's copies, by machine
            tree,
            self.machines,
            state_dir=state,
            backups_dir=self.backups_dir,
            threads=self.threads,
            spool=self.spool,
            supervisor=self.delivery,
            intake=self.intake,
            port=self.port,
            lease=lease,
        )
        # What other parts of the gateway (the demo, Programs.Put's callers) call.
        self.submit_bytes = self.intake.submit_bytes
        self.machine_busy = self.delivery.machine_busy
        self.inbox: Inbox | None = None
        self._transports = contextlib.AsyncExitStack()
        self._opened = False

    # --- lifecycle ---------------------------------------------------------------------------------

    async def __aenter__(self) -> Self:
        for folder in (self.spool.root, self.intake.rejected_dir, self.backups_dir):
            folder.mkdir(parents=True, exist_ok=True)
        try:
            await self.threads.queue(self.queue.open)
        except JobError as exc:
            raise SinkError(str(exc)) from None
        self._opened = self.port.opened = True
        try:
            for transport in self.delivery.transports.values():
                await self._transports.enter_async_context(transport)
            await self.delivery.publish_all()
            await self.intake.resume()
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
        await self.intake.cancel()
        await self._transports.aclose()  # serial lines closed, punch desks drained, before the queue
        if self._opened:
            self._opened = self.port.opened = False
            await self.threads.queue(self.queue.close)
        await self.threads.shutdown()

    def _build_inbox(self) -> Inbox | None:
        cfg = self.config.gateway.inbox
        if not cfg.enabled:
            log.info(
                "the FTP inbox is disabled (inbox.enabled: false); jobs arrive only through Programs.Put"
            )
            return None
        try:
            refused = [] if self.queue.shares_programs else list(self.elsewhere)
            accounts = Accounts.from_config(cfg, self.accepts, self.environ, elsewhere=refused)
        except ConfigError as exc:
            raise SinkError(f"FTP inbox: {exc}") from None
        if not len(accounts):
            log.warning("the FTP inbox is not started: the gateway file's inbox section has no accounts")
            return None
        tls = tls_context(self.config.state_dir, cfg.tls.cert, cfg.tls.key) if cfg.tls is not None else None
        return Inbox(
            cfg,
            root=self.intake.inbox_root,
            machines=self.accepts,
            accounts=accounts,
            logins=self.logins,
            submit=self.intake.submit,
            tls=tls,
            jobs_coming=functools.partial(self.threads.warm, ready),
            check_upload=self._upload_check,
        )

    def _upload_check(self, machine: str) -> UploadCheck | None:
        """A check for an upload as it streams in; None where the reader is pure Python (it would hold the
        GIL for seconds: the validation process does that work instead)."""
        if compiled.plain is None or machine not in self.accepts:
            return None
        return UploadCheck(self.accepts[machine].validation, self.threads.checking)

    async def run(self) -> None:
        """Deliver and publish until cancelled (the delivery supervisor)."""
        await self.delivery.run()
