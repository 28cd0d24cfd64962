"""The COPYDATA sink: every machine's targets, each with its own emitter, transport and tasks.

One sink per gateway (implements gateway.sinks.base.Sink). The status
variables (`Status/CopydataTargets`, `Status/CopydataFeedback`) are added when
the sink is built, before any sink starts, so that OPC UA and MQTT show them
from the beginning. A target that cannot work on this system (`win32` outside
Windows) stops the start with a SinkError naming it; a receiver that is absent
or slow never does.
"""

from __future__ import annotations

import asyncio
import logging
from contextlib import AsyncExitStack
from typing import Self

from gateway.model.tree import VariableTree
from gateway.sinks.copydata.emitter import Emitter
from gateway.sinks.copydata.status import CopydataStatus

log = logging.getLogger("gateway.sinks.copydata")


def has_targets(tree: VariableTree) -> bool:
    return any(m.mapping.copydata is not None for m in tree.machines.values())


class CopydataSink:
    """Frames for nesting software, for every machine whose mapping has `copydata.targets`."""

    name = "copydata"

    def __init__(self, tree: VariableTree) -> None:
        self.tree = tree
        self.statuses: dict[str, CopydataStatus] = {}
        self.emitters: list[Emitter] = []
        for machine in tree.machines.values():
            copydata = machine.mapping.copydata
            if copydata is None:
                continue
            status = CopydataStatus(machine)
            self.statuses[machine.name] = status
            for target in copydata.targets:
                self.emitters.append(Emitter(machine, target, status))
        self._stack = AsyncExitStack()

    def emitter(self, machine: str, target: str) -> Emitter:
        for emitter in self.emitters:
            if emitter.machine.name == machine and emitter.target.name == target:
                return emitter
        raise KeyError(f"{machine}/{target}")

    @property
    def endpoint(self) -> str:
        """Where the targets send, for the start-up log."""
        return ", ".join(f"{e.name} {e.target.describe()}" for e in self.emitters)

    async def __aenter__(self) -> Self:
        try:
            for emitter in self.emitters:
                await self._stack.enter_async_context(emitter)
        except BaseException:
            await self._stack.aclose()
            raise
        log.info("COPYDATA: %d target(s): %s", len(self.emitters), self.endpoint)
        for emitter in self.emitters:
            emitter.feedback.report_writers()
        return self

    async def __aexit__(self, *exc_info: object) -> None:
        await self._stack.aclose()

    async def run(self) -> None:
        async with asyncio.TaskGroup() as tg:
            for emitter in self.emitters:
                tg.create_task(emitter.run(), name=f"copydata:{emitter.name}")
