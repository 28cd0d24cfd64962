"""The in-process source: changes pushed straight into `Machine.ingest`, to measure the sinks alone.

It paces itself with the simulator's noise pacer (simulator/noise.py): the value is
the change's sequence number, written round robin over the variables, and the
source timestamp is the wall clock at the moment of the push.

`hold` (optional) makes it a source that always has more to give but never more than the gateway
can keep: while it answers True (say, the MQTT sink has that many changes waiting), the injector
waits instead of writing. Flat out with a hold, a QoS 1 sink is measured at its capacity without a
backlog that grows until store-and-forward drops changes (issue 28's row: every change delivered).
"""

from __future__ import annotations

import asyncio
import math
from collections.abc import Callable, Sequence
from datetime import UTC, datetime

from gateway.model.tree import VariableNode
from simulator.noise import Pacer

HOLD_POLL = 0.002  # s between looks at `hold` while it holds the injector back


class Injector(Pacer):
    def __init__(self, nodes: Sequence[VariableNode], hold: Callable[[], bool] | None = None) -> None:
        if not nodes:
            raise ValueError("nothing to inject into")
        super().__init__()
        self.nodes = list(nodes)
        self.hold = hold
        self.held = 0  # times it waited for the gateway

    async def run(self) -> None:
        nodes = self.nodes
        count = len(nodes)
        ingests = [(node, node.machine.ingest) for node in nodes]
        hold = self.hold
        while True:
            if hold is not None and math.isinf(self.rate) and hold():  # flat out only: a set rate is paced
                self.held += 1
                # Polls: the sink's figures change by callback and acknowledgement, with no event to await.
                while hold():  # noqa: ASYNC110
                    await asyncio.sleep(HOLD_POLL)
                self.set_rate(self.rate)  # count afresh: time spent held back is not lag
            due = await self.owed()
            stamp = datetime.now(UTC)
            seq = self.written
            for _ in range(due):
                seq += 1
                node, ingest = ingests[(seq - 1) % count]
                ingest(node, float(seq), stamp)
            self.written = seq
            await asyncio.sleep(0)
