"""A shard of `cnc-gateway fleet` stops when its supervisor is gone.

A supervisor killed with SIGKILL (or the OOM killer) cannot stop its shards. Left running, they keep
their ports, state directories and machines, and the supervisor started again would start a second set
beside them that cannot bind and fights them for the machines. So each shard is told its supervisor's pid
(`SUPERVISOR_ENV`) and watches its parent: once the parent is no longer that process, the shard sends
itself SIGTERM and stops cleanly, as when the supervisor stops it.
"""

from __future__ import annotations

import asyncio
import logging
import os
import signal
from collections.abc import Callable, Coroutine, Mapping

log = logging.getLogger("gateway.fleet")

SUPERVISOR_ENV = "CNC_FLEET_SUPERVISOR"  # the supervisor's pid, set in each shard's environment
CHECK_EVERY = 1.0  # s between looks at the parent


def supervisor_of(environ: Mapping[str, str]) -> int | None:
    """The pid of the supervisor this process is a shard of, or None (not started by `cnc-gateway fleet`)."""
    text = environ.get(SUPERVISOR_ENV, "").strip()
    return int(text) if text.isdigit() else None


async def stop_when_orphaned(supervisor: int, check_every: float = CHECK_EVERY) -> None:
    """Until cancelled, or until the parent is not `supervisor` any more: then SIGTERM to this process."""
    # Polled: no event says that a parent died (short of PR_SET_PDEATHSIG, which Python does not offer).
    while os.getppid() == supervisor:  # noqa: ASYNC110
        await asyncio.sleep(check_every)
    log.warning("fleet: this shard's supervisor (pid %d) is gone: stopping", supervisor)
    os.kill(os.getpid(), signal.SIGTERM)  # the clean stop a signal gets (gateway.app.run_until_signalled)
    await asyncio.Event().wait()  # until that stop cancels this task


Extra = tuple[str, Callable[[], Coroutine[object, object, None]]]


def orphan_watch(environ: Mapping[str, str]) -> list[Extra]:
    """The named task `Gateway.run` adds for a shard of a fleet; none for a gateway run on its own."""
    supervisor = supervisor_of(environ)
    if supervisor is None:
        return []
    return [("fleet:supervisor-watch", lambda: stop_when_orphaned(supervisor))]
