"""aioftp's server side: its handler decorators typed for subclasses, and a stop without tracebacks.

aioftp annotates ConnectionConditions, PathConditions, PathPermissions and `worker` for handlers whose
`self` is `aioftp.Server` itself, so the methods of a subclass (the gateway's inbox, the simulator's
program store), which aioftp calls with that subclass, do not fit them under mypy --strict. The
decorators here are aioftp's own, typed to give back the handler they were given.

`close_server` is how every aioftp server here stops (the inbox, the simulator's program store).

`PeerCheckedServer` is the server every FTP server here is built on: aioftp hands the first TCP
connection to a passive port to the session, whoever made it, so anyone who can reach the port could
send the bytes of someone else's upload (or read their download). Like vsftpd (`pasv_promiscuous=NO`)
and ProFTPD (`AllowForeignAddress off`), it takes a data connection only from the control
connection's host.
"""

from __future__ import annotations

import asyncio
import ipaddress
import logging
from collections.abc import Awaitable, Callable
from typing import TypeVar, cast

import aioftp
from aioftp.common import Connection
from aioftp.server import ConnectionConditions, PathConditions, PathPermissions
from aioftp.server import worker as _worker

Handler = TypeVar("Handler", bound=Callable[..., Awaitable[bool]])

CLOSE_GRACE = 0.5  # s for sessions to end before the server is closed

USER_REQUIRED = ConnectionConditions.user_required
LOGIN_REQUIRED = ConnectionConditions.login_required
PASSIVE_SERVER_STARTED = ConnectionConditions.passive_server_started
DATA_CONNECTION_MADE = ConnectionConditions.data_connection_made
RENAME_FROM_REQUIRED = ConnectionConditions.rename_from_required


def connection_conditions(
    *fields: tuple[str, str], wait: bool = False, fail_code: str = "503", fail_info: str | None = None
) -> Callable[[Handler], Handler]:
    """`aioftp.server.ConnectionConditions`: the connection must have these fields (logged in, ...)."""
    conditions = ConnectionConditions(*fields, wait=wait, fail_code=fail_code, fail_info=fail_info)
    return cast("Callable[[Handler], Handler]", conditions)


def path_conditions(*conditions: tuple[str, bool, str]) -> Callable[[Handler], Handler]:
    """`aioftp.server.PathConditions`: the path argument must exist, be a file, ..."""
    return cast("Callable[[Handler], Handler]", PathConditions(*conditions))


def path_permissions(*permissions: str) -> Callable[[Handler], Handler]:
    """`aioftp.server.PathPermissions`: the user's permissions on the path argument."""
    return cast("Callable[[Handler], Handler]", PathPermissions(*permissions))


def worker(handler: Handler) -> Handler:
    """`aioftp.server.worker`: a handler that runs as a task the session may abort (ABOR)."""
    return cast(Handler, _worker(handler))


async def close_server(server: aioftp.Server, grace: float = CLOSE_GRACE) -> None:
    """Stop an aioftp server that has started, with no traceback in the log.

    aioftp's `Server.close()` cancels every session's task, and Python 3.11's asyncio
    reports each as an "exception in callback". So: stop listening, close every
    client's stream (the client sees its connection end, and its session task
    finishes on its own), give them `grace` seconds, then close. aioftp keeps a
    session's task only in a private attribute (`Connection._dispatcher`); this is
    the one place that reads it.
    """
    server.server.close()  # no new connections
    dispatchers = [c._dispatcher for c in server.connections.values()]
    for stream in list(server.connections):
        stream.close()
    if dispatchers:
        await asyncio.wait(dispatchers, timeout=grace)
    await server.close()


DataHandler = Callable[[asyncio.StreamReader, asyncio.StreamWriter], Awaitable[None]]


def same_host(a: str, b: str) -> bool:
    """Whether two peer addresses are one host (an IPv4-mapped IPv6 address is its IPv4 address)."""
    return _canonical(a) == _canonical(b)


def _canonical(address: str) -> str:
    try:
        ip = ipaddress.ip_address(address.split("%", 1)[0])
    except ValueError:
        return address
    if isinstance(ip, ipaddress.IPv6Address) and ip.ipv4_mapped is not None:
        return str(ip.ipv4_mapped)
    return str(ip)


class PeerCheckedServer(aioftp.Server):
    """aioftp's server, taking a passive data connection only from the host of the session's control
    connection. A connection from elsewhere is closed at once (reset, nothing read from it), counted in
    `foreign_data_connections` and logged; the session keeps waiting for its own, and a transfer that
    does not get one fails with 425 as any transfer without a data connection does.

    `pasv_promiscuous = True` turns the check off (vsftpd's option of that name), for the rare client
    whose data connections come from another address than its control connection.
    """

    pasv_promiscuous = False
    foreign_data_connections = 0
    log = logging.getLogger("gateway.shims.aioftp_server")

    async def _start_passive_server(
        self, connection: Connection, handler_callback: DataHandler
    ) -> asyncio.Server:
        async def checked(reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
            peer = writer.get_extra_info("peername")
            host = str(peer[0]) if isinstance(peer, (tuple, list)) and peer else ""
            if self.pasv_promiscuous or same_host(host, connection.client_host):
                await handler_callback(reader, writer)
                return
            writer.transport.abort()  # a reset: the sender learns nothing, and nothing it sent is read
            self.foreign_data_connections += 1
            self.refused_data_connection(connection, host)

        return await super()._start_passive_server(connection, checked)

    def refused_data_connection(self, connection: Connection, host: str) -> None:
        """Called for each data connection refused (already closed); logs it."""
        self.log.warning(
            "refused a data connection from %s to the passive port of the session of %s:%s: "
            "data connections are taken only from the session's own address",
            host,
            connection.client_host,
            connection.client_port,
        )
