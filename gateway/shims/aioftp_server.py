"""aioftp's server side: its handler decorators typed for subclasses, and a stop without tracebacks.

aioftp annotates ConnectionConditions, PathConditions, PathPermissions and `worker` for handlers whose
`self` is `aioftp.Server` itself, so the methods of a subclass (the gateway's inbox, the simulator's
program store), which aioftp calls with that subclass, do not fit them under mypy --strict. The
decorators here are aioftp's own, typed to give back the handler they were given.

`close_server` is how every aioftp server here stops (the inbox, the simulator's program store).
"""

from __future__ import annotations

import asyncio
from collections.abc import Awaitable, Callable
from typing import TypeVar, cast

import aioftp
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
