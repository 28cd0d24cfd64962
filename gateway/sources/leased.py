"""Machines served by lease (`shard: lease`): a machine's source runs only while this process holds its lease.

Every shard loads the whole fleet and builds every machine's source; `LeasedSource` wraps each one
and starts the real source's `run()` when the LeaseHolder says the machine is held here, and cancels
it when the lease is lost (renewal refused, or this process's own clock no longer trusts the last
renewal). Meanwhile the machine is on standby: `Machine.served` is False (the MQTT and Sparkplug faces
publish nothing of it, so a standby shard's Bad values never overwrite the serving shard's), its
status says `standby`, its values are Bad, and writes to it are refused as for a controller that is
away. `Status/Served` and `Status/ServiceLevel` say the same to OPC UA clients that keep a connection
to every shard (non-transparent redundancy, OPC UA Part 4: the client takes each machine from the
server whose ServiceLevel for it is highest).
"""

from __future__ import annotations

import asyncio
import logging
from typing import Any, Self

from gateway.errors import ControllerUnavailable
from gateway.model.sample import ReadBack
from gateway.model.status import STANDBY_STATUS
from gateway.model.tree import VariableNode
from gateway.shards.holder import LeaseHolder
from gateway.sources.base import Source

log = logging.getLogger("gateway.shards")

# A machine folder's ServiceLevel (OPC UA Part 4's ranges: 200-255 healthy, 1 no data here).
SERVED_LEVEL = 255
STANDBY_LEVEL = 1
STANDBY_REASON = "served by another shard (shard: lease)"


class LeasedSource:
    """A machine's source, run while this process holds the machine's lease (a Source itself)."""

    def __init__(self, inner: Source, holder: LeaseHolder) -> None:
        self.inner = inner
        self.machine = inner.machine
        self.holder = holder
        machine = self.machine
        self.served_node = machine.add_internal(
            "Status/Served", "Boolean", "True while this process serves the machine (holds its lease)", False
        )
        self.level_node = machine.add_internal(
            "Status/ServiceLevel",
            "Byte",
            "OPC UA Part 4 ServiceLevel of this machine on this server: 255 served here, 1 served by another",
            STANDBY_LEVEL,
        )
        self._held = asyncio.Event()
        self._lost = asyncio.Event()
        self._lost.set()
        holder.watch(machine.name, self._told)
        self.takeovers = 0  # how often this process took the machine (its lease arrived)

    def __repr__(self) -> str:
        return f"<LeasedSource {self.inner!r}>"

    def _told(self, held: bool) -> None:
        (self._held if held else self._lost).set()
        (self._lost if held else self._held).clear()

    async def __aenter__(self) -> Self:
        await self.inner.__aenter__()
        self.machine.writer = self  # writes pass through the lease check below
        self._standby()
        return self

    async def __aexit__(self, *exc_info: object) -> None:
        if self.machine.writer is self:
            self.machine.writer = None
        await self.inner.__aexit__(*exc_info)

    async def run(self) -> None:
        name = self.machine.name
        while True:
            await self._held.wait()
            self.takeovers += 1
            log.info("%s: served by this process (lease held, fencing token %s)", name, self._token())
            self._serve()
            try:
                async with asyncio.TaskGroup() as group:
                    running = group.create_task(self.inner.run(), name=f"source:{name}:leased")
                    await self._lost.wait()
                    running.cancel()
            finally:
                self._standby()
            log.info("%s: no longer served by this process (its lease is lost or released)", name)

    def _token(self) -> str:
        fence = self.holder.fence(self.machine.name)
        return "?" if fence is None else str(fence.token)

    def _serve(self) -> None:
        machine = self.machine
        machine.served = True  # first: the faces publish what follows (the source's first values)
        machine.set_internal(self.served_node, True)
        machine.set_internal(self.level_node, SERVED_LEVEL)
        machine.status.error("")  # the standby's reason no longer holds
        machine.status.connecting()

    def _standby(self) -> None:
        machine = self.machine
        if machine.served:
            machine.served = False  # first: the faces publish nothing of what follows
        machine.invalidate(STANDBY_STATUS, STANDBY_REASON)
        machine.status.standby(STANDBY_REASON)
        machine.set_internal(self.served_node, False)
        machine.set_internal(self.level_node, STANDBY_LEVEL)

    async def write(self, node: VariableNode, raw: Any) -> ReadBack | None:
        """Only on the holder's fencing token by this process's clock: a shard that lost the machine (or
        cannot be sure it still holds it) refuses, as for a controller that is away."""
        if self.holder.fence(self.machine.name) is None:
            raise ControllerUnavailable(f"{self.machine.name} is {STANDBY_REASON}: write to that shard")
        return await self.inner.write(node, raw)
