"""The inbox's read-only side: folders, listings and the small commands real FTP clients send.

A mixin of InboxServer (gateway/jobs/inbox/server.py), kept apart so that each
module stays readable. Everything here only looks: CWD, LIST/MLSD/NLST/MLST,
SIZE, MDTM, FEAT, NOOP, OPTS, ALLO, MODE, STRU and SITE (aioftp lacks most of
them); paths are resolved by the server's `_where`, which applies
gateway.jobs.inbox.paths.
"""

from __future__ import annotations

import asyncio
import functools
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path, PurePosixPath
from typing import TYPE_CHECKING, Any, cast

import aioftp
from aioftp.common import Connection

from gateway.errors import PathRefused
from gateway.jobs.inbox.accounts import Account
from gateway.jobs.inbox.listing import FEATURES, Entry, list_line, mdtm, mlsx_facts, split_list_argument
from gateway.jobs.inbox.paths import TMP, InboxPath
from gateway.shims.aioftp_server import LOGIN_REQUIRED, PASSIVE_SERVER_STARTED, Handler, connection_conditions

if TYPE_CHECKING:
    from gateway.config.jobs import InboxConfig


@dataclass
class Session:
    client: str  # host:port
    account: Account | None = None
    login: str = ""
    files: int = 0
    busy: int = 0  # uploads in progress (data transfer and commit): the session is not idle
    failures: int = 0
    priority: int = 0
    last_activity: float = field(default_factory=time.monotonic)
    login_by: float = float("inf")  # time.monotonic() by which it must have logged in (inbox.login_timeout)
    foreign_data: int = 0  # data connections from other addresses refused since the last transfer
    closing: bool = False  # closed by the server (idle, no login): no further command is read


def session_of(connection: Connection) -> Session | None:
    future = dict.get(connection, "session")
    return future.result() if future is not None and future.done() else None


def refusals(handler: Handler) -> Handler:
    """Answer a PathRefused raised by a command handler with its FTP code and reason."""

    @functools.wraps(handler)
    async def wrapper(self: Any, connection: Connection, rest: Any, *args: Any) -> bool:
        try:
            return await handler(self, connection, rest, *args)
        except PathRefused as exc:
            connection.response(exc.code, exc.reason)
            return True

    return cast(Handler, wrapper)


login_required = connection_conditions(LOGIN_REQUIRED)


class BrowseCommands:
    """Folders, listings and small commands; mixed into InboxServer, which provides the path helpers."""

    config: InboxConfig
    root: Path
    encoding: str
    wait_future_timeout: float | None

    if TYPE_CHECKING:

        def _where(self, connection: Connection, rest: str | PurePosixPath) -> InboxPath: ...

        def _real(self, place: InboxPath) -> Path: ...

        def _existing_file(
            self, connection: Connection, rest: str | PurePosixPath
        ) -> tuple[InboxPath, Path, Any]: ...

    def _entries(self, place: InboxPath, session: Session) -> list[Entry]:
        assert session.account is not None
        if place.kind == "root":
            out = []
            for machine in sorted(session.account.machines):
                st = (self.root / machine).stat()
                out.append(Entry(machine, True, 0, st.st_mtime))
            return out
        real = self._real(place)
        if place.kind == "file":
            try:
                st = real.stat()
            except OSError:
                raise PathRefused(f"{place.virtual}: no such file") from None
            return [Entry(real.name, False, st.st_size, st.st_mtime)]
        out = []
        for child in sorted(real.iterdir()):
            if child.name.startswith(".") or child.is_symlink():
                continue
            st = child.stat()
            if child.is_dir():
                if place.kind == "machine" and child.name == TMP:
                    out.append(Entry(child.name, True, 0, st.st_mtime))
            else:
                out.append(Entry(child.name, False, st.st_size, st.st_mtime))
        return out

    async def _data_connection(self, connection: Connection) -> aioftp.ThrottleStreamIO | None:
        """The session's data connection, once its client has made it; None (425 answered) if none came
        from the session's own address in time (aioftp's PASV and the peer check of PeerCheckedServer)."""
        session = session_of(connection)
        try:
            async with asyncio.timeout(self.wait_future_timeout):
                await asyncio.shield(connection.future.data_connection)
        except TimeoutError:
            refused = session.foreign_data if session is not None else 0
            if refused:
                connection.response(
                    "425",
                    f"can't open data connection: {refused} from another address than this session's "
                    "refused (inbox.pasv_promiscuous)",
                )
            else:
                connection.response("425", "can't open data connection")
            return None
        finally:
            if session is not None:
                session.foreign_data = 0
        stream: aioftp.ThrottleStreamIO = connection.data_connection  # what aioftp's PASV made
        del connection.data_connection
        return stream

    # --- folders ---------------------------------------------------------------------------------

    @login_required
    @refusals
    async def cwd(self, connection: Connection, rest: str | PurePosixPath) -> bool:
        place = self._where(connection, rest or "/")
        if place.kind == "file":
            raise PathRefused(f"{place.virtual}: no such folder")
        connection.current_directory = PurePosixPath(place.virtual)
        connection.response("250", f'"{place.virtual}" is the current folder')
        return True

    @login_required
    async def cdup(self, connection: Connection, rest: str | PurePosixPath) -> bool:
        return await self.cwd(connection, str(PurePosixPath(str(connection.current_directory)).parent))

    @login_required
    @refusals
    async def mkd(self, connection: Connection, rest: str | PurePosixPath) -> bool:
        place = self._where(connection, rest)
        if place.kind != "tmp":
            raise PathRefused("only a machine's tmp/ folder exists here; it cannot be created elsewhere")
        self._real(place).mkdir(exist_ok=True)
        connection.response("257", f'"{place.virtual}" exists')
        return True

    @login_required
    async def rmd(self, connection: Connection, rest: str | PurePosixPath) -> bool:
        connection.response("550", "folders cannot be removed")
        return True

    # --- listings --------------------------------------------------------------------------------

    @connection_conditions(LOGIN_REQUIRED, PASSIVE_SERVER_STARTED)
    @refusals
    async def list(self, connection: Connection, rest: str | PurePosixPath) -> bool:
        return self._listing(connection, rest, list_line)

    @connection_conditions(LOGIN_REQUIRED, PASSIVE_SERVER_STARTED)
    @refusals
    async def mlsd(self, connection: Connection, rest: str | PurePosixPath) -> bool:
        return self._listing(connection, rest, mlsx_facts)

    @connection_conditions(LOGIN_REQUIRED, PASSIVE_SERVER_STARTED)
    @refusals
    async def nlst(self, connection: Connection, rest: str) -> bool:
        return self._listing(connection, rest, lambda e: e.name)

    def _listing(
        self, connection: Connection, rest: str | PurePosixPath, fmt: Callable[[Entry], str]
    ) -> bool:
        session = session_of(connection)
        assert session is not None
        place = self._where(connection, split_list_argument(str(rest)))
        lines = [fmt(e) for e in self._entries(place, session)]
        task = asyncio.create_task(self._send_lines(connection, lines), name="inbox:listing")
        connection.extra_workers.add(task)
        connection.response("150", "listing follows")
        return True

    async def _send_lines(self, connection: Connection, lines: Sequence[str]) -> bool:
        try:
            stream = await self._data_connection(connection)
            if stream is None:
                return True
            async with stream:
                await stream.write("".join(line + "\r\n" for line in lines).encode(self.encoding))
        except asyncio.CancelledError:
            connection.response("426", "listing aborted")
            return True
        except (OSError, TimeoutError):
            connection.response("426", "the data connection failed")
            return True
        connection.response("226", "listing sent")
        return True

    @login_required
    @refusals
    async def mlst(self, connection: Connection, rest: str | PurePosixPath) -> bool:
        session = session_of(connection)
        assert session is not None
        place = self._where(connection, rest)
        if place.kind == "file":
            entry = self._entries(place, session)[0]
        else:
            st = (self._real(place)).stat()
            entry = Entry(place.virtual, True, 0, st.st_mtime)
        connection.response("250", [f"Listing {place.virtual}", mlsx_facts(entry), "End"], True)
        return True

    @login_required
    @refusals
    async def size(self, connection: Connection, rest: str) -> bool:
        _, _, st = self._existing_file(connection, rest)
        connection.response("213", str(st.st_size))
        return True

    @login_required
    @refusals
    async def mdtm(self, connection: Connection, rest: str) -> bool:
        _, _, st = self._existing_file(connection, rest)
        connection.response("213", mdtm(st.st_mtime))
        return True

    # --- small commands real clients send ----------------------------------------------------------

    async def feat(self, connection: Connection, rest: str) -> bool:
        connection.response("211", ["Features:", *FEATURES, "End"], True)
        return True

    async def noop(self, connection: Connection, rest: str) -> bool:
        connection.response("200", "NOOP ok")
        return True

    async def opts(self, connection: Connection, rest: str) -> bool:
        if rest.strip().upper().startswith("UTF8"):
            connection.response("200", "UTF-8 is always on")
        else:
            connection.response("501", f"option {rest.strip()!r} not supported")
        return True

    @login_required
    async def allo(self, connection: Connection, rest: str) -> bool:
        words = rest.split()
        if words and words[0].isdigit() and int(words[0]) > self.config.max_file_size:
            connection.response("552", f"files are limited to {int(self.config.max_file_size)} bytes")
        else:
            connection.response("202", "no allocation needed")
        return True

    async def mode(self, connection: Connection, rest: str) -> bool:
        ok = rest.strip().upper() == "S"
        connection.response("200" if ok else "504", "stream mode" if ok else "only stream mode (S)")
        return True

    async def stru(self, connection: Connection, rest: str) -> bool:
        ok = rest.strip().upper() == "F"
        connection.response("200" if ok else "504", "file structure" if ok else "only file structure (F)")
        return True

    @login_required
    async def site(self, connection: Connection, rest: str) -> bool:
        session = session_of(connection)
        assert session is not None
        words = rest.split()
        if len(words) == 2 and words[0].upper() == "PRIORITY":
            try:
                session.priority = max(-1000, min(1000, int(words[1])))
            except ValueError:
                connection.response("501", "SITE PRIORITY needs a whole number")
                return True
            connection.response("200", f"uploads in this session get priority {session.priority}")
        elif words and words[0].upper() == "HELP":
            connection.response("214", "SITE PRIORITY <n>: higher runs first (default 0)")
        else:
            connection.response("502", "SITE commands: PRIORITY, HELP")
        return True
