"""The in-process source: changes pushed straight into `Machine.ingest`, to measure the sinks alone.

It paces itself like the simulator's noise (simulator/noise.py): the value is
the change's sequence number, written round robin over the variables, and the
source timestamp is the wall clock at the moment of the push.
"""

from __future__ import annotations

import asyncio
import math
import time
from collections.abc import Sequence
from datetime import UTC, datetime
from typing import Any

from gateway.model.tree import VariableNode

CHUNK = 1000
TICK = 0.005
MAX_CATCH_UP = 0.25


class Injector:
    def __init__(self, nodes: Sequence[VariableNode]) -> None:
        if not nodes:
            raise ValueError("nothing to inject into")
        self.nodes = list(nodes)
        self.written = 0
        self.lagged = 0
        self.rate = 0.0
        self._since = time.monotonic()
        self._at_set = 0
        self._pace = (self._since, 0)
        self._wake = asyncio.Event()

    def set_rate(self, rate: float) -> None:
        self.rate = rate
        self._since = time.monotonic()
        self._at_set = self.written
        self._pace = (self._since, self.written)
        self._wake.set()

    def stats(self) -> dict[str, Any]:
        elapsed = time.monotonic() - self._since
        done = self.written - self._at_set
        return {
            "written": self.written,
            "lagged": self.lagged,
            "rate": self.rate,
            "achieved": done / elapsed if elapsed > 0 else 0.0,
        }

    async def run(self) -> None:
        nodes = self.nodes
        count = len(nodes)
        ingests = [(node, node.machine.ingest) for node in nodes]
        while True:
            rate = self.rate
            if rate <= 0:
                self._wake.clear()
                await self._wake.wait()
                continue
            if math.isinf(rate):
                due = CHUNK
            else:
                now = time.monotonic()
                since, base = self._pace
                owed = (now - since) * rate - (self.written - base)
                if owed > rate * MAX_CATCH_UP:
                    self.lagged += int(owed)
                    self._pace = (now, self.written)
                    owed = 0.0
                if owed < 1:
                    await asyncio.sleep(max(TICK, (1 - owed) / rate))
                    continue
                due = min(int(owed), CHUNK)
            stamp = datetime.now(UTC)
            seq = self.written
            for _ in range(due):
                seq += 1
                node, ingest = ingests[(seq - 1) % count]
                ingest(node, float(seq), stamp)
            self.written = seq
            await asyncio.sleep(0)
