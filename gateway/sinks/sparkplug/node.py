"""The edge node's own metrics (NBIRTH, then NDATA when they change): the gateway as a whole.

    Gateway/Version            String   the gateway's version
    Gateway/Machines           UInt32   machines (devices) of this edge node
    Gateway/MachinesConnected  UInt32   of those, the ones whose controller is reachable
    Gateway/MqttDropped        UInt64   changes the JSON topics' buffer dropped (Status/MqttDropped, summed)
    Sparkplug/Dropped          UInt64   DDATA messages this node's store-and-forward dropped
    Sparkplug/Stored           UInt64   DDATA messages waiting to go out as historical data
    Sparkplug/CommandsRefused  UInt64   NCMD/DCMD metrics refused (by kind in the log and the sink)
    Jobs/QueueLength           UInt32   jobs waiting or being sent, all machines
    Jobs/Sending               UInt32   machines a job is being sent to now
    Jobs/FailedCount           UInt32   FAILED jobs waiting for a retry or cancel, all machines

Read from the tree's variables (`Status/…`, `Jobs/…`) and from the sink's counters, never from the
job queue itself: a sink does not reach into another component.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable
from dataclasses import dataclass

from gateway import __version__
from gateway.codecs.sparkplug import Aliases, Metric, MetricTable
from gateway.model.tree import VariableTree
from gateway.model.types import TypeSpec


@dataclass(frozen=True, slots=True)
class NodeMetric:
    name: str
    spec: TypeSpec
    read: Callable[[], object]
    alias: int


@dataclass(frozen=True, slots=True)
class SinkCounters:
    """What the sink tells its own metrics."""

    dropped: Callable[[], int]
    stored: Callable[[], int]
    refused: Callable[[], int]


class NodeMetrics:
    """The metrics of the NBIRTH besides bdSeq and Node Control/Rebirth (which the codec adds)."""

    def __init__(self, tree: VariableTree, aliases: Aliases, counters: SinkCounters) -> None:
        self.tree = tree
        t = TypeSpec.parse
        table: list[tuple[str, str, Callable[[], object]]] = [
            ("Gateway/Version", "String", lambda: __version__),
            ("Gateway/Machines", "UInt32", lambda: len(tree.machines)),
            (
                "Gateway/MachinesConnected",
                "UInt32",
                lambda: sum(1 for m in tree.machines.values() if m.status.is_connected),
            ),
            ("Gateway/MqttDropped", "UInt64", lambda: self._sum("Status/MqttDropped")),
            ("Sparkplug/Dropped", "UInt64", counters.dropped),
            ("Sparkplug/Stored", "UInt64", counters.stored),
            ("Sparkplug/CommandsRefused", "UInt64", counters.refused),
            ("Jobs/QueueLength", "UInt32", lambda: self._sum("Jobs/QueueLength")),
            ("Jobs/Sending", "UInt32", lambda: sum(1 for v in self._values("Jobs/Current") if v)),
            ("Jobs/FailedCount", "UInt32", lambda: self._sum("Jobs/FailedCount")),
        ]
        self.metrics = [
            NodeMetric(name, t(kind), read, aliases.alias(None, name)) for name, kind, read in table
        ]
        self.table = MetricTable.from_metrics(self.current(0))
        self._sent: dict[str, object] = {}

    def _values(self, path: str) -> Iterable[object]:
        for machine in self.tree.machines.values():
            node = machine.nodes.get(path)
            if node is not None and node.sample.good:
                yield node.sample.value

    def _sum(self, path: str) -> int:
        return sum(int(v) for v in self._values(path) if isinstance(v, int))

    def current(self, ts: int) -> list[Metric]:
        """Every node metric with its value now (for the NBIRTH); what it says is what NDATA compares with."""
        out = [Metric(m.name, m.spec, m.read(), ts, m.alias) for m in self.metrics]
        self._sent = {m.name: m.value for m in out}
        return out

    def changed(self, ts: int) -> list[Metric]:
        """The node metrics whose value differs from the last NBIRTH or NDATA (for the next NDATA)."""
        out = []
        for m in self.metrics:
            value = m.read()
            if self._sent.get(m.name) != value:
                self._sent[m.name] = value
                out.append(Metric(m.name, m.spec, value, ts, m.alias))
        return out
