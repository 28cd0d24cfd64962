"""The source interface: a driver that keeps one machine's variables up to date.

A source is an async context manager with a long-running `run()`. It pushes
values into the tree with `Machine.ingest`, turns them bad with
`Machine.invalidate` when the controller is unreachable, reports its connection
through `Machine.status`, and carries out writes the tree has already checked.
It never raises out of `run()` for a controller problem: it retries with backoff.
"""

from __future__ import annotations

from typing import Any, Protocol, Self

from gateway.config.mapping import MachineMapping
from gateway.model.sample import ReadBack
from gateway.model.tree import Machine, VariableNode


class Source(Protocol):
    machine: Machine

    async def __aenter__(self) -> Self: ...

    async def __aexit__(self, *exc_info: object) -> None: ...

    async def run(self) -> None:
        """Connect, subscribe, and reconnect with backoff, until cancelled."""
        ...

    async def write(self, node: VariableNode, raw: Any) -> ReadBack | None:
        """Write a raw (already checked and unscaled) value. Raises ControllerRefused/ControllerUnavailable.

        Answers with the value read back from the controller after the write (None if it
        could not be read), which the tree takes in before the write is answered.
        """
        ...


def create_source(machine: Machine, mapping: MachineMapping) -> Source:
    """The driver named by the machine's mapping (its `driver:` section and per-variable settings)."""
    driver = mapping.driver
    if driver.type == "opcua":
        from gateway.sources.opcua_client import OpcUaSource

        return OpcUaSource(machine, mapping)
    if driver.type == "mtconnect":
        from gateway.sources.mtconnect.agent_source import MTConnectSource

        return MTConnectSource(machine, mapping)
    if driver.type == "shdr":
        from gateway.sources.mtconnect.shdr_source import ShdrSource

        return ShdrSource(machine, mapping)
    if driver.type == "modbus":
        from gateway.sources.modbus.source import ModbusSource

        return ModbusSource(machine, mapping)
    raise ValueError(f"unknown driver type {driver.type!r}")  # config validation makes this unreachable
