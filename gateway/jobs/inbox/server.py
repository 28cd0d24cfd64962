"""The inbox's FTP server: sessions, logins, uploads and their commit (aioftp's server side).

aioftp provides the protocol engine (sessions, passive data connections, TLS);
every command that touches a path is replaced, here and in the BrowseCommands
mixin, so that gateway.jobs.inbox.paths decides what a client may see and write and
nothing is resolved by aioftp's own path logic. See gateway/jobs/inbox/inbox.py for
how an upload is judged complete.

aioftp's handler decorators, its graceful stop and the check that a passive data connection
comes from the session's own address come from gateway/shims/aioftp_server.py (the simulator's
program store uses them too).

What an attacker on the network meets before it can upload anything: a passive port that takes
only the session's own address (`pasv_promiscuous`), a session cap per address
(`max_connections_per_address`), `login_timeout` seconds to log in, and the gateway's failed-login
lockout (`access.lockout`, shared with OPC UA and the web console: gateway/auth/lockout.py).
Each refusal is logged and counted in `InboxServer.refusals`.
"""

from __future__ import annotations

import asyncio
import hashlib
import logging
import os
import ssl
import time
import uuid
from collections import Counter, OrderedDict
from collections.abc import Awaitable, Callable
from dataclasses import dataclass
from pathlib import Path, PurePosixPath
from typing import TYPE_CHECKING, Any

import aioftp
from aioftp.common import Connection
from aioftp.server import AbstractUserManager

from gateway.auth.lockout import locked_out, login_failed
from gateway.auth.ratelimit import LoginLimiter
from gateway.config.jobs import InboxConfig
from gateway.errors import JobStoreError, PathRefused
from gateway.jobs.inbox.accounts import Accounts
from gateway.jobs.inbox.browse import BrowseCommands, Session, login_required, refusals, session_of
from gateway.jobs.inbox.paths import InboxPath, resolve
from gateway.shims.aioftp_server import (
    LOGIN_REQUIRED,
    PASSIVE_SERVER_STARTED,
    RENAME_FROM_REQUIRED,
    USER_REQUIRED,
    PeerCheckedServer,
    connection_conditions,
    same_host,
)

# Only named here; the job service makes them.
if TYPE_CHECKING:
    from gateway.jobs.validation.upload_check import UploadCheck

log = logging.getLogger("gateway.jobs.inbox")

BLOCK = 64 * 1024
COMMIT_GRACE = 0.25  # s the control connection must outlive the data connection of a plain STOR
LOGIN_FAILURE_DELAY = 0.5  # s before a wrong password is answered
MAX_LOGIN_FAILURES = 3  # then the session is closed
STAGING = ".staging"  # under the inbox root: plain STORs in progress; not visible to clients
IDLE, GONE, NO_LOGIN = "\x00idle", "\x00gone", "\x00no-login"  # pseudo-commands from parse_command


@dataclass(frozen=True, slots=True)
class Upload:
    """A complete upload, handed over to the job service (which now owns `path`)."""

    machine: str
    filename: str
    path: Path
    size: int
    sha256: str
    user: str
    client: str
    priority: int = 0
    check: UploadCheck | None = None  # the content checked as it arrived (same size and digest), if it was


@dataclass(frozen=True, slots=True)
class UploadReply:
    ok: bool
    message: str
    job_id: str | None = None
    transient: bool = False  # not kept, for a reason that should pass (451: send it again later)


Submit = Callable[[Upload], Awaitable[UploadReply]]
#: A new UploadCheck for an upload to this machine's folder, or None (no checking while uploads arrive).
CheckUpload = Callable[[str], "UploadCheck | None"]
#: Uploads to temporary names whose checks wait for the rename that commits them.
MAX_WAITING_CHECKS = 16


@dataclass(frozen=True, slots=True)
class _Checked:
    """An upload to a temporary name, checked as it arrived; valid while the file is unchanged."""

    machine: str
    size: int
    digest: str
    stamp: tuple[int, int, int]  # (inode, size, mtime in ns) right after the upload
    check: UploadCheck


def _stamp(path: Path) -> tuple[int, int, int]:
    st = path.stat()
    return st.st_ino, st.st_size, st.st_mtime_ns


class _Users(AbstractUserManager):
    """Every USER gets 331 (so user names cannot be probed); PASS is checked by InboxServer.pass_.

    aioftp keeps per-user state keyed by the User object for the server's lifetime, so
    there is one User object for all logins (the login name itself is kept in the Session).
    """

    def __init__(self, root: Path) -> None:
        super().__init__()
        self.shared = aioftp.User(login="inbox", base_path=root, home_path="/")

    async def get_user(
        self, login: str
    ) -> tuple[AbstractUserManager.GetUserResponse, aioftp.User | None, str]:
        return AbstractUserManager.GetUserResponse.PASSWORD_REQUIRED, self.shared, "password required"

    async def authenticate(
        self, user: aioftp.User, password: str
    ) -> bool:  # pragma: no cover - pass_ is ours
        return False


class InboxServer(BrowseCommands, PeerCheckedServer):
    def __init__(
        self,
        config: InboxConfig,
        root: Path,
        accounts: Accounts,
        submit: Submit,
        tls: ssl.SSLContext | None,
        jobs_coming: Callable[[], None] | None = None,
        check_upload: CheckUpload | None = None,
        logins: LoginLimiter | None = None,
    ) -> None:
        super().__init__(
            _Users(root),
            block_size=BLOCK,
            socket_timeout=config.transfer_timeout,
            idle_timeout=None,  # see parse_command
            wait_future_timeout=min(config.transfer_timeout, 30.0),
            maximum_connections=config.max_connections,
            ipv4_pasv_forced_response_address=config.passive_address,
            data_ports=config.passive_ports.ports if config.passive_ports else None,
            ssl=tls,
            welcome_message="cnc-gateway job inbox",
        )
        self.config = config
        self.root = root
        self.accounts = accounts
        self.submit = submit
        self.pasv_promiscuous = config.pasv_promiscuous
        #: The failed-login lockout: the gateway's, shared with its other doors (gateway/auth/lockout.py).
        self.logins = logins if logins is not None else LoginLimiter()
        #: What was turned away, by reason (for the log's reader, the tests and the drills).
        self.refusals: Counter[str] = Counter()
        #: Files an upload is writing to right now (the sweep of stale temporary files leaves them).
        self.receiving: set[Path] = set()
        #: Called when a client logs in: the job service gets its validation process ready (starting
        #: one takes a few tenths of a second; idempotent, and a process that died is started anew).
        self.jobs_coming = jobs_coming
        self.check_upload = check_upload
        self._waiting: OrderedDict[Path, _Checked] = OrderedDict()
        self.commands_mapping.update(
            {
                "size": self.size,
                "mdtm": self.mdtm,
                "feat": self.feat,
                "noop": self.noop,
                "opts": self.opts,
                "allo": self.allo,
                "mode": self.mode,
                "stru": self.stru,
                "nlst": self.nlst,
                "site": self.site,
                "xpwd": self.pwd,
                IDLE: self._idle,
                GONE: self._gone,
                NO_LOGIN: self._no_login,
            }
        )

    # --- the control connection ------------------------------------------------------------------

    async def greeting(self, connection: Connection, rest: str | PurePosixPath) -> bool:
        """A new session: turned away (421) when its address has too many already, or the server has."""
        host = connection.client_host
        connection.session = Session(
            f"{host}:{connection.client_port}", login_by=time.monotonic() + self.config.login_timeout
        )
        # One address never takes every slot: at most max_connections - 1 of them, whatever the setting.
        cap = min(self.config.max_connections_per_address, max(1, self.config.max_connections - 1))
        if sum(1 for c in self.connections.values() if same_host(c.client_host, host)) > cap:
            self.refusals["too many from one address"] += 1
            log.warning(
                "inbox: refused a session from %s: it has %d already (inbox.max_connections_per_address)",
                host,
                cap,
            )
            connection.response("421", f"too many connections from your address (at most {cap})")
            return False
        if self.available_connections.locked():
            self.refusals["too many connections"] += 1
            log.warning(
                "inbox: refused a session from %s: %d sessions open (inbox.max_connections)",
                host,
                self.config.max_connections,
            )
        return await super().greeting(connection, rest)

    async def parse_command(
        self, stream: aioftp.StreamIO, censor_commands: tuple[str] = ("pass",)
    ) -> tuple[str, str]:
        """Read one command. Idle sessions (no command, no transfer) end, and so do sessions not logged in
        within `login_timeout` (whatever they send meanwhile); a vanished client ends quietly."""
        connection = self.connections.get(stream)
        idle = self.config.idle_timeout
        while True:
            session = session_of(connection) if connection is not None else None
            if session is not None and session.closing:  # aioftp reads on while the session ends: wait to be
                await asyncio.get_running_loop().create_future()  # cancelled, so that it ends only once
            ending = self._ending(session)
            if ending is not None:
                return ending, ""
            wait = idle
            if session is not None:
                now = time.monotonic()
                if not session.busy:
                    wait = idle - (now - session.last_activity)
                if session.account is None:
                    wait = min(wait, session.login_by - now)
            try:
                async with asyncio.timeout(max(wait, 0.05)):
                    line = await stream.reader.readline()
            except TimeoutError:
                continue
            except (OSError, ValueError, asyncio.IncompleteReadError):
                return GONE, ""
            break
        if not line:
            return GONE, ""
        if session is not None:
            session.last_activity = time.monotonic()
        text = line.decode(self.encoding, errors="replace").rstrip("\r\n")
        cmd, _, rest = text.partition(" ")
        log.debug("%s %s", cmd, "***" if cmd.lower() in censor_commands else rest)
        return cmd.lower(), rest

    def _ending(self, session: Session | None) -> str | None:
        """NO_LOGIN (not logged in within login_timeout), IDLE (no command and no transfer for idle_timeout)
        or None; a session that ends is marked as closing."""
        if session is None:
            return None
        now = time.monotonic()
        if session.account is None and now >= session.login_by:
            session.closing = True
            return NO_LOGIN
        if not session.busy and now - session.last_activity >= self.config.idle_timeout:
            session.closing = True
            return IDLE
        return None

    async def response_writer(self, stream: aioftp.StreamIO, response_queue: asyncio.Queue[Any]) -> None:
        """aioftp's, except that a client gone away is not an error (the reader ends the session)."""
        while True:
            args = await response_queue.get()
            try:
                await self.write_response(stream, *args)
            except (OSError, TimeoutError):
                pass
            finally:
                response_queue.task_done()

    async def _idle(self, connection: Connection, rest: str) -> bool:
        connection.response("421", f"idle for {self.config.idle_timeout:g} s: closing the session")
        return False

    async def _gone(self, connection: Connection, rest: str) -> bool:
        return False

    async def _no_login(self, connection: Connection, rest: str) -> bool:
        session = session_of(connection)
        self.refusals["no login in time"] += 1
        log.info(
            "inbox: closed the session of %s: not logged in within %g s (inbox.login_timeout)",
            session.client if session is not None else connection.client_host,
            self.config.login_timeout,
        )
        connection.response(
            "421", f"not logged in within {self.config.login_timeout:g} s: closing the session"
        )
        return False

    async def user(self, connection: Connection, rest: str) -> bool:
        session = session_of(connection)
        if session is not None:
            if session.account is not None:  # logging in anew: the time to do it starts now
                session.login_by = time.monotonic() + self.config.login_timeout
            session.login = rest.strip()
            session.account = None
        return await super().user(connection, rest)

    @connection_conditions(USER_REQUIRED)
    async def pass_(self, connection: Connection, rest: str) -> bool:
        session = session_of(connection)
        assert session is not None
        if connection.future.logged.done():
            connection.response("503", "already logged in")
            return True
        login, address = session.login, connection.client_host
        wait = locked_out(self.logins, login, address, "FTP")
        if wait:  # refused unchecked: no scrypt work for the guesser's passwords
            self.refusals["locked out"] += 1
            connection.response(
                "530", f"login refused: too many failed logins from your address; try again in {wait:.0f} s"
            )
            return False
        account = await asyncio.to_thread(self.accounts.authenticate, login, rest)
        if account is None:
            session.failures += 1
            self.refusals["wrong password"] += 1
            login_failed(self.logins, login, address, "FTP", "wrong password or unknown user")
            await asyncio.sleep(LOGIN_FAILURE_DELAY)
            connection.response("530", "login incorrect")
            return session.failures < MAX_LOGIN_FAILURES
        session.account = account
        connection.logged = True
        connection.current_directory = PurePosixPath("/")
        folders = ", ".join(f"/{m}/" for m in sorted(account.machines)) or "none"
        log.info("inbox: %s logged in from %s", account.user, session.client)
        if self.jobs_coming is not None:
            self.jobs_coming()
        connection.response("230", f"logged in; machine folders: {folders}")
        return True

    # --- passive data connections ----------------------------------------------------------------

    def refused_data_connection(self, connection: Connection, host: str) -> None:
        session = session_of(connection)
        if session is not None:
            session.foreign_data += 1
        self.refusals["foreign data connection"] += 1
        log.warning(
            "inbox: refused a data connection from %s to the passive port of %s (%s): only the session's "
            "own address may connect (inbox.pasv_promiscuous)",
            host,
            session.client if session is not None else connection.client_host,
            (session.account.user if session.account else session.login or "not logged in")
            if session is not None
            else "?",
        )

    # --- paths -----------------------------------------------------------------------------------

    def _where(self, connection: Connection, rest: str | PurePosixPath) -> InboxPath:
        session = session_of(connection)
        assert session is not None and session.account is not None
        account = session.account
        place = resolve(str(connection.current_directory), str(rest), account.machines, account.elsewhere)
        real = self.root
        for part in place.parts:
            real = real / part
            if real.is_symlink():
                raise PathRefused("symbolic links are not followed")
        return place

    def _real(self, place: InboxPath) -> Path:
        return self.root.joinpath(*place.parts)

    def _file(self, connection: Connection, rest: str | PurePosixPath) -> tuple[InboxPath, Path]:
        place = self._where(connection, rest)
        if place.kind != "file":
            raise PathRefused(f"{place.virtual} is a folder")
        return place, self._real(place)

    def _existing_file(
        self, connection: Connection, rest: str | PurePosixPath
    ) -> tuple[InboxPath, Path, os.stat_result]:
        place, real = self._file(connection, rest)
        try:
            st = real.stat()
        except OSError:
            raise PathRefused(f"{place.virtual}: no such file") from None
        return place, real, st

    def _staging(self) -> Path:
        return self.root / STAGING / uuid.uuid4().hex

    # --- files ---------------------------------------------------------------------------------------

    @login_required
    async def retr(self, connection: Connection, rest: str | PurePosixPath) -> bool:
        connection.response("550", "the inbox is write-only: programs leave it when they are queued")
        return True

    @login_required
    @refusals
    async def dele(self, connection: Connection, rest: str | PurePosixPath) -> bool:
        place, real, _ = self._existing_file(connection, rest)
        real.unlink()
        self._waiting.pop(real, None)
        connection.response("250", f"{place.virtual} deleted")
        return True

    @login_required
    @refusals
    async def rnfr(self, connection: Connection, rest: str | PurePosixPath) -> bool:
        place, _, _ = self._existing_file(connection, rest)
        connection.rename_from = place
        connection.response("350", "ready for RNTO")
        return True

    @connection_conditions(LOGIN_REQUIRED, RENAME_FROM_REQUIRED)
    @refusals
    async def rnto(self, connection: Connection, rest: str | PurePosixPath) -> bool:
        source: InboxPath = connection.rename_from
        del connection.rename_from
        target, target_real = self._file(connection, rest)
        source_real = self._real(source)
        if not source_real.is_file():
            raise PathRefused(f"{source.virtual}: no such file")
        waiting = self._waiting.pop(source_real, None)
        if target.is_temporary(self.config.temp_suffixes):
            if target_real.exists():
                raise PathRefused(f"{target.virtual} exists")
            os.replace(source_real, target_real)
            if waiting is not None:
                self._waiting[target_real] = waiting
            connection.response("250", f"renamed to {target.virtual}")
            return True
        staging = self._staging()
        os.replace(source_real, staging)
        check = None
        if waiting is not None and waiting.machine == target.machine and waiting.stamp == _stamp(staging):
            # Unchanged since it was checked on the way in: its size and digest are known too.
            size, digest, check = waiting.size, waiting.digest, waiting.check
        else:
            size, digest = await asyncio.to_thread(_digest, staging)
        if size > self.config.max_file_size:
            staging.unlink(missing_ok=True)
            connection.response("552", f"{target.name} is larger than {int(self.config.max_file_size)} bytes")
            return True
        reply = await self._commit(connection, target, staging, size, digest, check)
        connection.response("250" if reply.ok else _refusal(reply), reply.message)
        return True

    @connection_conditions(LOGIN_REQUIRED, PASSIVE_SERVER_STARTED)
    @refusals
    async def stor(self, connection: Connection, rest: str | PurePosixPath, mode: str = "wb") -> bool:
        session = session_of(connection)
        assert session is not None
        place, real = self._file(connection, rest)
        temporary = place.is_temporary(self.config.temp_suffixes)
        offset = connection.restart_offset
        if (offset or mode == "ab") and not temporary:
            raise PathRefused("resuming (REST, APPE) works only for temporary names such as *.part")
        if session.files >= self.config.max_files_per_session:
            connection.response("552", f"{self.config.max_files_per_session} files per session: log in again")
            return True
        if offset and (not real.is_file() or offset > real.stat().st_size):
            raise PathRefused(f"cannot resume {place.virtual} at byte {offset}", "554")
        # Where the new bytes start: REST's offset, the end of the file for APPE, else 0. The size limit
        # counts the whole file, so appends cannot grow a temporary file past max_file_size.
        start = offset if offset or mode != "ab" or not real.is_file() else real.stat().st_size
        if start and start >= self.config.max_file_size:
            raise PathRefused(
                f"{place.name} already has the {int(self.config.max_file_size)} bytes allowed", "552"
            )
        session.files += 1
        target = real if temporary else self._staging()
        if temporary:
            real.parent.mkdir(exist_ok=True)
        task = asyncio.create_task(
            self._receive(connection, session, place, target, temporary, mode, start), name="inbox:stor"
        )
        connection.extra_workers.add(task)
        connection.response("150", "ready to receive")
        return True

    async def appe(self, connection: Connection, rest: str | PurePosixPath) -> bool:
        return await self.stor(connection, rest, "ab")

    async def _receive(
        self,
        connection: Connection,
        session: Session,
        place: InboxPath,
        target: Path,
        temporary: bool,
        mode: str,
        start: int,
    ) -> bool:
        """The data side of STOR/APPE (new bytes from `start`); answers the client itself, never raises."""
        assert place.machine is not None  # a file's place (`_file`) names its machine
        handed_over = False
        session.busy += 1
        self.receiving.add(target)
        try:
            stream = await self._data_connection(connection)
            if stream is None:
                return True
            self._waiting.pop(target, None)  # a new upload, an append or a resume: an earlier check is void
            check = (
                self.check_upload(place.machine) if self.check_upload and not start and mode == "wb" else None
            )
            size, digest = await self._copy(stream, place, target, mode, start, check)
            if temporary:
                if check is not None:
                    self._wait(target, _Checked(place.machine, size, digest, _stamp(target), check))
                connection.response(
                    "226", f"stored {place.virtual}; rename it into /{place.machine}/ to submit it"
                )
                return True
            # A client killed mid-transfer closes both connections; wait to see the control one survive.
            await asyncio.sleep(COMMIT_GRACE)
            handed_over = True
            reply = await self._commit(connection, place, target, size, digest, check)
            connection.response("226" if reply.ok else _refusal(reply), reply.message)
            return True
        except _TooLarge:
            connection.response("552", f"{place.name} is larger than {int(self.config.max_file_size)} bytes")
            return True
        except asyncio.CancelledError:
            if not handed_over:
                log.info(
                    "inbox: upload of %s from %s did not complete; discarded", place.virtual, session.client
                )
                connection.response("426", "transfer aborted; nothing was kept")
                connection.response("226", "abort done")
            return True
        except (ConnectionError, TimeoutError, asyncio.IncompleteReadError) as exc:
            log.info(
                "inbox: upload of %s from %s failed (%s); discarded",
                place.virtual,
                session.client,
                type(exc).__name__,
            )
            connection.response("426", "the data connection failed; nothing was kept")
            return True
        except OSError as exc:
            log.error("inbox: cannot store %s: %s", place.virtual, exc.strerror or exc)
            connection.response("452", f"cannot store the file: {exc.strerror or exc}")
            return True
        finally:
            session.busy -= 1
            session.last_activity = time.monotonic()
            self.receiving.discard(target)
            if not handed_over and not temporary:
                target.unlink(missing_ok=True)  # noqa: ASYNC240 - one unlink of a failed upload's file

    def forget(self, path: Path) -> None:
        """`path` was deleted (a stale temporary upload): a check kept for its rename is void."""
        self._waiting.pop(path, None)

    def _wait(self, path: Path, checked: _Checked) -> None:
        """Keep the check of an upload to a temporary name for its rename (the oldest go beyond a few)."""
        self._waiting[path] = checked
        while len(self._waiting) > MAX_WAITING_CHECKS:
            self._waiting.popitem(last=False)

    async def _copy(
        self,
        stream: aioftp.ThrottleStreamIO,
        place: InboxPath,
        target: Path,
        mode: str,
        start: int,
        check: UploadCheck | None = None,
    ) -> tuple[int, str]:
        """Data connection to file from byte `start`, the whole file within the size limit, fed to `check`
        too; (size, SHA-256) of what arrived. Too large: the file is cut back to `start` bytes."""
        digest = hashlib.sha256()
        limit = int(self.config.max_file_size)
        size = start
        # The blocks go to the page cache as they arrive, in the loop (a thread hop per block costs more than
        # the write); the one fsync at the end blocks the loop for as long as the disk takes.
        with open(target, "r+b" if start else mode) as out:  # noqa: ASYNC230 - see above
            if start:
                out.seek(start)
                out.truncate()
            async with stream:
                async for block in stream.iter_by_block(BLOCK):
                    size += len(block)
                    if size > limit:
                        out.truncate(start)
                        raise _TooLarge
                    out.write(block)
                    digest.update(block)
                    if check is not None:
                        await check.feed(block)
            out.flush()
            os.fsync(out.fileno())
        return size, digest.hexdigest()

    async def _commit(
        self,
        connection: Connection,
        place: InboxPath,
        staged: Path,
        size: int,
        digest: str,
        check: UploadCheck | None = None,
    ) -> UploadReply:
        session = session_of(connection)
        assert session is not None and session.account is not None and place.machine and place.name
        upload = Upload(
            machine=place.machine,
            filename=place.name,
            path=staged,
            size=size,
            sha256=digest,
            user=session.account.user,
            client=session.client,
            priority=session.priority,
            check=check,
        )
        try:
            reply = await self.submit(upload)
            return UploadReply(reply.ok, " ".join(reply.message.split()), reply.job_id)  # one FTP reply line
        except asyncio.CancelledError:
            raise
        except JobStoreError as exc:  # the queue's database is away: nothing was kept, the sender may retry
            log.warning("inbox: %s not taken: %s", place.virtual, exc)
            staged.unlink(missing_ok=True)  # noqa: ASYNC240 - one unlink, on a failure that is logged
            # The reason stays in the log: the database's address is not the sender's business.
            return UploadReply(
                False, "the job queue is unavailable: the upload was not kept; send it again", transient=True
            )
        except Exception:
            log.exception("inbox: the job service failed on %s", place.virtual)
            staged.unlink(missing_ok=True)  # noqa: ASYNC240 - one unlink, on a failure that is logged
            return UploadReply(False, "internal error: the upload was not kept")


def _refusal(reply: UploadReply) -> str:
    """451 (local error, try again) for what should pass, as a queue whose database is away; else 550."""
    return "451" if reply.transient else "550"


class _TooLarge(Exception):
    pass


def _digest(path: Path) -> tuple[int, str]:
    h = hashlib.sha256()
    size = 0
    with path.open("rb") as f:
        while block := f.read(1024 * 1024):
            size += len(block)
            h.update(block)
    return size, h.hexdigest()
