"""After delivery: select the program on the controller, and start it, through mapped variables.

Only through the tree's ordinary write path (`Machine.write`), so access, type
and range checks, write hooks and the controller's own refusal all apply, as
for any other client. When the mapping names a `ready` condition (say
`Machine/State` equals 0, Idle), the program is selected only once the machine
is ready, and a start counts as confirmed when the machine leaves that state.

The outcome is a sentence for the job's record; auto-start never fails a job
that was delivered.
"""

from __future__ import annotations

import asyncio
import logging
import time
from typing import Any

from gateway.config.jobs import AutoStart
from gateway.errors import RequestError
from gateway.jobs.queue.store import Job
from gateway.model.context import WriteContext
from gateway.model.tree import Machine

log = logging.getLogger("gateway.jobs.autostart")

POLL = 0.1  # s between looks at the ready variable
SELECT_TRIES = 3  # a machine can turn busy between "ready" and our select


class AutoStarter:
    def __init__(self, machine: Machine, auto: AutoStart, folder: str) -> None:
        self.machine = machine
        self.auto = auto
        self.folder = folder.rstrip("/")
        self.waiting: Job | None = (
            None  # the job waiting to be started (the demo's driver keeps out of the way)
        )

    @property
    def busy(self) -> bool:
        return self.waiting is not None

    def ready(self) -> bool:
        cond = self.auto.ready
        if cond is None:
            return True
        node = self.machine.nodes.get(cond.path)
        if node is None or not node.sample.good:
            return False
        return _same(node.sample.value, cond.equals)

    async def _until(self, predicate: Any, timeout: float) -> bool:
        deadline = time.monotonic() + timeout
        while not predicate():
            if time.monotonic() >= deadline:
                return False
            await asyncio.sleep(POLL)
        return True

    def select_value(self, job: Job, name: str) -> str:
        kind = self.auto.select_value
        if kind == "path":
            return f"{self.folder}/{name}"
        if kind == "program" and job.program_name:
            return job.program_name
        return name

    async def run(self, job: Job, name: str) -> str:
        """Select and/or start `job` (delivered as `name`); returns what happened, in words."""
        auto = self.auto
        ctx = WriteContext("jobs", job.user or None)
        self.waiting = job
        try:
            for attempt in range(1, SELECT_TRIES + 1):
                if not await self._until(self.ready, auto.ready_timeout):
                    return f"not started: {self._ready_text()} did not hold within {auto.ready_timeout:g} s"
                try:
                    if auto.select is not None:
                        await self.machine.write(auto.select, self.select_value(job, name), ctx)
                    if auto.start is not None:
                        await self.machine.write(auto.start, True, ctx)
                except RequestError as exc:
                    if attempt == SELECT_TRIES:
                        return f"not started: {exc.reason} ({exc.status})"
                    log.info(
                        "%s: auto-start of %s refused (%s); waiting for the machine again",
                        self.machine.name,
                        job.id,
                        exc.reason,
                    )
                    await asyncio.sleep(POLL)
                    continue
                break
            if auto.start is None:
                return f"selected {name}"
            if auto.ready is None:
                return f"selected and started {name}"
            if await self._until(lambda: not self.ready(), auto.confirm_timeout):
                return f"started {name}"
            return (
                f"start of {name} sent, but {self._ready_text()} still holds after {auto.confirm_timeout:g} s"
            )
        finally:
            self.waiting = None

    def _ready_text(self) -> str:
        cond = self.auto.ready
        return f"{cond.path} = {cond.equals!r}" if cond is not None else "ready"


def _same(value: Any, wanted: Any) -> bool:
    if isinstance(wanted, bool) or isinstance(value, bool):
        return value is wanted or (value == wanted and type(value) is type(wanted))
    if isinstance(wanted, (int, float)) and isinstance(value, (int, float)):
        return float(value) == float(wanted)
    return bool(value == wanted)
