"""A read-only snapshot of a running gateway's internal counters: backlogs, coalescing, drops, quality.

For benchmarks and for support ("is the gateway keeping up?"): whether a backlog
grows is the difference between a gateway that keeps up and one that only looks
as if it did. Everything here reads public attributes and counters and changes
nothing, so it is safe to call at any time from the gateway's event loop (it
costs one pass over the variables, about a millisecond per 10,000).
"""

from __future__ import annotations

import gc
import time
from collections.abc import Sequence
from typing import Any, Protocol

from gateway.model.tree import VariableTree
from gateway.sinks.base import Sink


class Observed(Protocol):
    """What a snapshot reads of a running gateway (gateway.app.Gateway is one)."""

    @property
    def tree(self) -> VariableTree: ...

    @property
    def sinks(self) -> Sequence[Sink]: ...


def snapshot(gateway: Observed) -> dict[str, Any]:
    """Counters of the change hub, the sinks and the machines, as plain JSON-ready data."""
    tree = gateway.tree
    hub = {
        sub.name: {
            "backlog": sub.backlog,
            "coalesced": sub.coalesced,
            "delivered": sub.delivered,
            "every_change": sub.every_change,
        }
        for sub in tree.hub.subscriptions
    }
    sinks = {sink.name: sink.health().figures() for sink in gateway.sinks}
    machines = {}
    for name, machine in tree.machines.items():
        mapped = good = 0
        for node in machine.mapped:
            mapped += 1
            if node.sample.good:
                good += 1
        machines[name] = {"variables": mapped, "good": good, "state": machine.status.state}
    return {"hub": hub, "sinks": sinks, "machines": machines, "gc": GC_PAUSES.stats()}


class GcPauses:
    """How long Python's cyclic garbage collector stopped the process, per generation.

    Every sink waits while it runs, so its passes show up directly as latency; this
    tells a collector pause from a slow sink. Off until `install()` (a callback per pass).
    """

    def __init__(self) -> None:
        self.installed = False
        self._started = 0.0
        self.count = [0, 0, 0]
        self.total = [0.0, 0.0, 0.0]  # seconds
        self.longest = [0.0, 0.0, 0.0]

    def install(self) -> None:
        if not self.installed:
            gc.callbacks.append(self._callback)
            self.installed = True

    def _callback(self, phase: str, info: dict[str, int]) -> None:
        if phase == "start":
            self._started = time.perf_counter()
            return
        took = time.perf_counter() - self._started
        gen = info.get("generation", 2)
        self.count[gen] += 1
        self.total[gen] += took
        if took > self.longest[gen]:
            self.longest[gen] = took

    def stats(self) -> dict[str, Any]:
        return {
            "installed": self.installed,
            "count": list(self.count),
            "total_ms": [round(t * 1000, 1) for t in self.total],
            "longest_ms": [round(t * 1000, 1) for t in self.longest],
        }


GC_PAUSES = GcPauses()
