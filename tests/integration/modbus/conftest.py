"""The Modbus driver over real TCP: a variable tree and the driver alone (`polling`), or the whole gateway."""

from __future__ import annotations

import asyncio
from collections.abc import AsyncIterator
from contextlib import asynccontextmanager
from typing import Any

from gateway.config.mapping import MachineMapping
from gateway.model.context import WriteContext
from gateway.model.tree import Machine, VariableTree
from gateway.sources.modbus.source import ModbusSource

MACHINE = "aux"
ADMIN = WriteContext("test", "tester", "admin")


def modbus_mapping(port: int, variables: list[dict[str, Any]], **driver: Any) -> MachineMapping:
    settings = {
        "type": "modbus",
        "host": "127.0.0.1",
        "port": port,
        "timeout": 0.5,
        "reconnect": {"initial": 0.05, "max": 0.3, "factor": 2},
        **driver,
    }
    return MachineMapping.model_validate(
        {
            "machine": MACHINE,
            "driver": settings,
            "defaults": {"sampling_interval": 50},
            "variables": variables,
        }
    )


@asynccontextmanager
async def polling(mapping: MachineMapping) -> AsyncIterator[tuple[Machine, ModbusSource]]:
    """The tree's machine and its Modbus driver, running."""
    tree = VariableTree([mapping.definition()])
    machine = tree.machines[mapping.machine]
    async with ModbusSource(machine, mapping) as source:
        task = asyncio.create_task(source.run(), name="modbus")
        try:
            yield machine, source
        finally:
            task.cancel()
            await asyncio.gather(task, return_exceptions=True)


def sample(machine: Machine, path: str) -> Any:
    return machine.nodes[path].sample
