"""The COPYDATA sink: every machine's targets, each with its own emitter, transport and tasks.

One sink per gateway (implements gateway.sinks.base.Sink). The status
variables (`Status/CopydataTargets`, `Status/CopydataFeedback`) are added when
the sink is built, before any sink starts, so that OPC UA and MQTT show them
from the beginning. A target that cannot work on this system (`win32` outside
Windows) stops the start with a SinkError naming it; a receiver that is absent
or slow never does.

`make_transport` picks each target's transport; it lives here, not beside the
emitter, because the transports depend on the emitter's port (port.py) and
importing them from the emitter would close a cycle.
"""

from __future__ import annotations

import asyncio
import logging
import sys
from collections.abc import Mapping
from contextlib import AsyncExitStack
from typing import Self

from gateway.errors import SinkError
from gateway.model.tree import VariableTree
from gateway.sinks.base import SinkHealth
from gateway.sinks.copydata.config import CopydataMachineEntry
from gateway.sinks.copydata.emitter import Emitter
from gateway.sinks.copydata.port import Transport, TransportPort
from gateway.sinks.copydata.status import CopydataStatus

log = logging.getLogger("gateway.sinks.copydata")


def has_targets(mappings: Mapping[str, CopydataMachineEntry]) -> bool:
    return any(m.copydata is not None for m in mappings.values())


class CopydataSink:
    """Frames for nesting software, for every machine whose mapping has `copydata.targets`."""

    name = "copydata"

    def __init__(self, tree: VariableTree, mappings: Mapping[str, CopydataMachineEntry]) -> None:
        self.tree = tree
        self.statuses: dict[str, CopydataStatus] = {}
        self.emitters: list[Emitter] = []
        for machine in tree.machines.values():
            mapping = mappings.get(machine.name)
            copydata = mapping.copydata if mapping is not None else None
            if mapping is None or copydata is None:
                continue
            status = CopydataStatus(machine)
            self.statuses[machine.name] = status
            for target in copydata.targets:
                self.emitters.append(Emitter(machine, mapping, target, status, make_transport))
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

    def health(self) -> SinkHealth:
        """Always ready: a receiver may come at any time, and each target says its state in
        Status/CopydataTargets."""
        return SinkHealth(ready=True)

    async def run(self) -> None:
        async with asyncio.TaskGroup() as tg:
            for emitter in self.emitters:
                tg.create_task(emitter.run(), name=f"copydata:{emitter.name}")


def make_transport(port: TransportPort) -> Transport:
    """The target's transport; win32 is imported only on Windows, and refused elsewhere."""
    kind = port.target.transport
    if kind == "tcp-client":
        from gateway.sinks.copydata.tcp import TcpClientTransport

        return TcpClientTransport(port)
    if kind == "tcp-server":
        from gateway.sinks.copydata.tcp import TcpServerTransport

        return TcpServerTransport(port)
    if kind == "udp":
        from gateway.sinks.copydata.udp import UdpTransport

        return UdpTransport(port)
    if kind == "win32":
        if sys.platform != "win32":
            raise SinkError(
                f"COPYDATA target {port.name} uses transport win32 (WM_COPYDATA window messages), which "
                f"needs Windows, and this is {sys.platform}; run the gateway on the nesting software's PC, "
                "or use tcp-client, tcp-server or udp here"
            )
        from gateway.sinks.copydata.win32 import Win32Transport

        return Win32Transport(port)
    raise SinkError(f"COPYDATA target {port.name}: unknown transport {kind!r}")  # the config rules it out
