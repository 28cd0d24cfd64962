"""The example driver's source: counts in `counter` variables, keeps writes in `memory` ones."""

from __future__ import annotations

import asyncio
from typing import Any, Self

from cnc_example_driver.config import ExampleDriver
from gateway.errors import ControllerRefused
from gateway.model.sample import ReadBack, utcnow
from gateway.model.tree import Machine, VariableNode
from gateway.sources.base import DriverMapping, settings_of


class ExampleSource:
    def __init__(self, machine: Machine, mapping: DriverMapping) -> None:
        self.machine = machine
        self.driver = settings_of(mapping, ExampleDriver)
        self.counters = [n for n in machine.mapped if n.definition.source == "counter"]
        self.memory = [n for n in machine.mapped if n.definition.source != "counter"]

    async def __aenter__(self) -> Self:
        self.machine.writer = self  # writes the tree has checked come to write()
        return self

    async def __aexit__(self, *exc_info: object) -> None:
        if self.machine.writer is self:
            self.machine.writer = None

    async def run(self) -> None:
        """Count until cancelled. A real driver connects here, and on trouble calls
        machine.invalidate() and status.disconnected(reason), then retries with gateway.reconnect."""
        status = self.machine.status
        status.connecting()
        status.connected()
        now = utcnow()
        for node in self.memory:  # a memory starts at its type's zero
            self.machine.ingest(node, node.definition.raw_type.default(), now)
        count = 0
        try:
            while True:
                now = utcnow()
                for node in self.counters:
                    self.machine.ingest(node, count, now)
                count += 1
                await asyncio.sleep(self.driver.period)
        finally:
            status.disconnected("stopped")

    async def write(self, node: VariableNode, raw: Any) -> ReadBack | None:
        if node in self.counters:
            raise ControllerRefused(f"{node.path} is a counter: it counts, it is not written")
        return ReadBack(raw, utcnow())  # what the controller holds now, which the tree takes in
