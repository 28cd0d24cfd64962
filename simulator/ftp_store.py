"""The controller's FTP program store (aioftp), rooted at the store folder that holds DATA/Programs.

aioftp's server lacks SIZE and NLST and refuses RNTO onto an existing file;
`ProgramFtpServer` adds SIZE and NLST and lets a rename replace a file (POSIX
rename semantics, as vsftpd and many controller FTP servers do, so an upload
to a temporary name followed by RNFR/RNTO replaces a program atomically).
There is one user and no anonymous access, and a passive data connection is taken only
from the address of the session's control connection (`PeerCheckedServer`, as the gateway's
inbox does): the gateway delivers jobs here, and a host that raced it to the passive port
would otherwise have its own program stored in their place.

Two aioftp habits would put tracebacks in the log for ordinary events: it logs
every client that disconnects without QUIT as an exception, and closing the
server cancels connection tasks, which Python 3.11's asyncio reports as an
"exception in callback". `FtpStore` filters the first, and stops with
`close_server` (gateway/shims/aioftp_server.py, as the gateway's inbox does), which closes
client connections gracefully before closing the server.
"""

from __future__ import annotations

import asyncio
import logging
from pathlib import Path, PurePosixPath
from typing import Self

import aioftp
from aioftp.common import END_OF_LINE, Connection
from aioftp.server import PathConditions, PathPermissions

from gateway.shims.aioftp_server import (
    DATA_CONNECTION_MADE,
    LOGIN_REQUIRED,
    PASSIVE_SERVER_STARTED,
    RENAME_FROM_REQUIRED,
    PeerCheckedServer,
    close_server,
    connection_conditions,
    path_conditions,
    path_permissions,
    worker,
)
from simulator.errors import SimulatorError

log = logging.getLogger("simulator.ftp")


class _QuietDisconnects(logging.Filter):
    """Drop aioftp's traceback for a client that went away without QUIT: that is not an error."""

    def filter(self, record: logging.LogRecord) -> bool:
        exc = record.exc_info[1] if record.exc_info else None
        return not (record.msg == "dispatcher caught exception" and isinstance(exc, ConnectionError))


def _install_filter() -> None:
    logger = logging.getLogger("aioftp.server")
    if not any(isinstance(f, _QuietDisconnects) for f in logger.filters):
        logger.addFilter(_QuietDisconnects())


class ProgramFtpServer(PeerCheckedServer):
    log = log  # refused data connections are logged as the store's

    def __init__(self, root: Path, user: str, password: str) -> None:
        account = aioftp.User(
            login=user,
            password=password,
            base_path=root,
            home_path="/",
            permissions=[aioftp.Permission("/", readable=True, writable=True)],
        )
        super().__init__([account], welcome_message="cnc-simulator program store")
        self.commands_mapping["size"] = self.size
        self.commands_mapping["nlst"] = self.nlst

    @connection_conditions(LOGIN_REQUIRED)
    @path_conditions(PathConditions.path_must_exists, PathConditions.path_must_be_file)
    @path_permissions(PathPermissions.readable)
    async def size(self, connection: Connection, rest: str | PurePosixPath) -> bool:
        real_path, _virtual = self.get_paths(connection, rest)
        stat = await connection.path_io.stat(real_path)
        connection.response("213", str(stat.st_size))
        return True

    @connection_conditions(LOGIN_REQUIRED, RENAME_FROM_REQUIRED)
    @path_permissions(PathPermissions.writable)
    async def rnto(self, connection: Connection, rest: str | PurePosixPath) -> bool:
        real_path, _virtual = self.get_paths(connection, rest)
        rename_from = connection.rename_from
        del connection.rename_from
        if await connection.path_io.is_dir(real_path):
            connection.response("550", "target is a directory")
            return True
        await connection.path_io.rename(rename_from, real_path)  # replaces an existing file
        log.info("renamed %s to %s", rename_from.name, real_path.name)
        connection.response("250", "")
        return True

    @connection_conditions(LOGIN_REQUIRED, PASSIVE_SERVER_STARTED)
    @path_conditions(PathConditions.path_must_exists)
    @path_permissions(PathPermissions.readable)
    async def nlst(self, connection: Connection, rest: str | PurePosixPath) -> bool:
        """Names only, one per line (what `ftplib.FTP.nlst` and `curl --list-only` ask for)."""

        @connection_conditions(
            DATA_CONNECTION_MADE,
            wait=True,
            fail_code="425",
            fail_info="Can't open data connection",
        )
        @worker
        async def nlst_worker(
            self: ProgramFtpServer, connection: Connection, rest: str | PurePosixPath
        ) -> bool:
            stream = connection.data_connection
            del connection.data_connection
            async with stream:
                if await connection.path_io.is_dir(real_path):
                    names = [path.name async for path in connection.path_io.list(real_path)]
                else:
                    names = [real_path.name]
                for name in sorted(names):
                    await stream.write((name + END_OF_LINE).encode(encoding=self.encoding))
            connection.response("226", "list transfer done")
            return True

        real_path, _virtual = self.get_paths(connection, rest)
        task: asyncio.Task[bool] = asyncio.create_task(nlst_worker(self, connection, rest))
        connection.extra_workers.add(task)
        connection.response("150", "list transfer started")
        return True


class FtpStore:
    """The FTP server as an async context manager; `port` is the bound port (also when 0 was asked)."""

    def __init__(self, root: Path, *, host: str, port: int, user: str, password: str) -> None:
        self.root = root
        self.host = host
        self.port = port
        self._server = ProgramFtpServer(root, user, password)
        self._started = False

    async def __aenter__(self) -> Self:
        _install_filter()
        try:
            await self._server.start(self.host, self.port)
        except OSError as exc:
            raise SimulatorError(
                f"FTP server cannot listen on {self.host}:{self.port}: {exc.strerror or exc}"
            ) from None
        self._started = True
        self.port = self._server.address[1]
        return self

    @property
    def foreign_data_connections(self) -> int:
        """Data connections refused because they came from another address than their session's."""
        return self._server.foreign_data_connections

    async def __aexit__(self, *exc_info: object) -> None:
        if not self._started:
            return
        self._started = False
        await close_server(self._server)
