"""The in-process source: changes pushed straight into `Machine.ingest`, to measure the sinks alone.

It paces itself with the simulator's noise pacer (simulator/noise.py): the value is
the change's sequence number, written round robin over the variables, and the
source timestamp is the wall clock at the moment of the push.
"""

from __future__ import annotations

import asyncio
from collections.abc import Sequence
from datetime import UTC, datetime

from gateway.model.tree import VariableNode
from simulator.noise import Pacer


class Injector(Pacer):
    def __init__(self, nodes: Sequence[VariableNode]) -> None:
        if not nodes:
            raise ValueError("nothing to inject into")
        super().__init__()
        self.nodes = list(nodes)

    async def run(self) -> None:
        nodes = self.nodes
        count = len(nodes)
        ingests = [(node, node.machine.ingest) for node in nodes]
        while True:
            due = await self.owed()
            stamp = datetime.now(UTC)
            seq = self.written
            for _ in range(due):
                seq += 1
                node, ingest = ingests[(seq - 1) % count]
                ingest(node, float(seq), stamp)
            self.written = seq
            await asyncio.sleep(0)
