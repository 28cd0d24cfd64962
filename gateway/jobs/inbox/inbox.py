"""The job inbox: an FTP server (aioftp) with one folder per machine.

This module is the inbox as the gateway sees it: an async context manager,
its folders, TLS. The FTP protocol side (aioftp's server) is in server.py
and browse.py, the only modules that import aioftp's server API.

When is an upload complete? FTP ends a stream-mode upload by closing the data
connection, so a client that dies mid-STOR looks like one that finished. So:

- a temporary name (`*.part`, `*.tmp`, `*.filepart`, or the `tmp/` folder) is
  only stored; the RNFR/RNTO that gives it its real name commits it;
- a plain STOR is committed only if the data connection ended cleanly and the
  control connection is still alive a moment later (a killed client loses both
  at once). The validator's end-marker check is the second guard.

A committed upload is handed to `submit` (the JobService), whose verdict is the
FTP reply: `226 J000042 queued` or `550 J000043 rejected: …`. Nothing is kept
in a machine's folder after that: the folder is a drop box, not a store. A
temporary upload nobody renames is deleted after `temp_max_age` (sweep.py), at
start and while the inbox runs.

aioftp lacks SIZE, MDTM, FEAT, NOOP, OPTS, ALLO, MODE, STRU, NLST and SITE; they
are added there. Its idle timeout would also cut long uploads (it times the
control connection alone), so idle sessions are closed by the inbox instead.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import ssl
import time
from collections import Counter
from collections.abc import Callable, Collection
from pathlib import Path
from typing import Self

from gateway.auth.ratelimit import LoginLimiter
from gateway.config.jobs import InboxConfig, machines_allowed
from gateway.errors import SinkError
from gateway.jobs.inbox import sweep
from gateway.jobs.inbox.accounts import Accounts
from gateway.jobs.inbox.paths import TMP
from gateway.jobs.inbox.server import (
    STAGING,
    CheckUpload,
    InboxServer,
    Submit,
    Upload,
    UploadReply,
)
from gateway.shims.aioftp_server import close_server
from gateway.tls import server_context

__all__ = ["STAGING", "Inbox", "Submit", "Upload", "UploadReply", "tls_context"]

log = logging.getLogger("gateway.jobs.inbox")


def tls_context(state_dir: Path, cert: str, key: str) -> ssl.SSLContext:
    """The server context for implicit FTPS; SinkError says which file is missing or wrong."""
    return server_context(state_dir, cert, key, "FTP inbox")


class Inbox:
    """The FTP inbox as an async context manager. `port` is the bound port (also when 0 was asked)."""

    def __init__(
        self,
        config: InboxConfig,
        *,
        root: Path,
        machines: Collection[str],
        accounts: Accounts,
        submit: Submit,
        tls: ssl.SSLContext | None = None,
        jobs_coming: Callable[[], None] | None = None,
        check_upload: CheckUpload | None = None,
        logins: LoginLimiter | None = None,
    ) -> None:
        self.config = config
        self.root = root
        self.machines = sorted(machines)
        self.port = config.port
        self._server = InboxServer(config, root, accounts, submit, tls, jobs_coming, check_upload, logins)
        self._started = False
        self._sweeping: asyncio.Task[None] | None = None
        #: Stale temporary uploads deleted so far (at start and while running).
        self.swept = 0

    @property
    def logins(self) -> LoginLimiter:
        """The failed-login lockout the inbox applies (the gateway's, shared with its other doors)."""
        return self._server.logins

    @property
    def refusals(self) -> Counter[str]:
        """What the FTP server turned away, by reason: "foreign data connection", "locked out", …"""
        return self._server.refusals

    @property
    def url(self) -> str:
        scheme = "ftps" if self._server.ssl is not None else "ftp"
        host = "127.0.0.1" if self.config.host in ("0.0.0.0", "::", "") else self.config.host
        return f"{scheme}://{host}:{self.port}/"

    def prepare(self) -> list[str]:
        """Create the folders; discard uploads that a previous run left unfinished; what was discarded."""
        discarded = []
        staging = self.root / STAGING
        staging.mkdir(parents=True, exist_ok=True)
        for leftover in staging.iterdir():
            leftover.unlink(missing_ok=True)
            discarded.append(leftover.name)
        for machine in self.machines:
            (self.root / machine / TMP).mkdir(parents=True, exist_ok=True)
        self.sweep()
        return discarded

    def sweep(self) -> list[Path]:
        """Delete temporary uploads untouched for `temp_max_age` seconds; the ones deleted. Blocking."""
        server = self._server
        old = sweep.stale(
            self.root,
            self.machines,
            self.config.temp_suffixes,
            time.time() - self.config.temp_max_age,
            busy=server.receiving,
        )
        gone = sweep.delete(old)
        for path in gone:
            server.forget(path)
            log.info(
                "inbox: deleted %s: a temporary upload untouched for %g s (inbox.temp_max_age)",
                path.relative_to(self.root),
                self.config.temp_max_age,
            )
        self.swept += len(gone)
        return gone

    async def _sweep_while_running(self) -> None:
        """In the loop, not a thread: the uploads in progress cannot change while it looks (a few folders)."""
        every = sweep.every(self.config.temp_max_age)
        while True:
            await asyncio.sleep(every)
            self.sweep()

    async def __aenter__(self) -> Self:
        discarded = self.prepare()
        if discarded:
            log.warning("inbox: discarded %d unfinished upload(s) from the previous run", len(discarded))
        try:
            await self._server.start(self.config.host, self.config.port)
        except OSError as exc:
            raise SinkError(
                f"FTP inbox cannot listen on {self.config.host}:{self.config.port}: {exc.strerror or exc}"
            ) from None
        self._started = True
        self.port = self._server.address[1]
        self._sweeping = asyncio.create_task(self._sweep_while_running(), name="inbox:sweep")
        log.info("FTP inbox listening on %s (folders: %s)", self.url, ", ".join(self.machines))
        if self.config.anonymous:  # an explicit setting; say what it opens
            open_to = [m for m in self.machines if machines_allowed(self.config.anonymous_machines, m)]
            log.warning(
                "FTP inbox: anonymous logins (any password) may submit programs for %s: validated, "
                "queued, delivered, and started where the mapping has jobs.auto (inbox.anonymous)",
                ", ".join(open_to) or "no machine",
            )
        return self

    async def __aexit__(self, *exc_info: object) -> None:
        if not self._started:
            return
        self._started = False
        if self._sweeping is not None:
            self._sweeping.cancel()
            with contextlib.suppress(asyncio.CancelledError):
                await self._sweeping
            self._sweeping = None
        await close_server(self._server)
