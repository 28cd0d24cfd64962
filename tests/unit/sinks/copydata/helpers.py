"""A small machine with one variable of every kind a frame carries, built from a mapping dict."""

from __future__ import annotations

from typing import Any

from gateway.config.mapping import MachineMapping
from gateway.model.sample import utcnow
from gateway.model.tree import Machine, VariableNode, VariableTree
from gateway.sinks.copydata.sink import CopydataSink

VARIABLES: list[dict[str, Any]] = [
    {"path": "Axes/X/Position", "source": "ns=2;s=x", "type": "Double", "copydata": {"id": 1}},
    {"path": "Axes/Y/Position", "source": "ns=2;s=y", "type": "Double", "copydata": {"id": 2}},
    {"path": "Program/Block", "source": "ns=2;s=b", "type": "UInt32", "copydata": {"id": 5}},
    {"path": "Laser/On", "source": "ns=2;s=l", "type": "Boolean", "copydata": {"id": 7}},
    {"path": "Program/Name", "source": "ns=2;s=n", "type": "String", "copydata": {"id": 9}},
    {"path": "Alarms2/Texts", "source": "ns=2;s=t", "type": "String[]", "copydata": {"id": 11}},
    {"path": "Program/Start", "source": "ns=2;s=s", "type": "DateTime", "copydata": {"id": 12}},
    {"path": "Laser/Table", "source": "ns=2;s=p", "type": "Double[]", "copydata": {"id": 13}},
    {
        "path": "Feed/Override",
        "source": "ns=2;s=o",
        "type": "UInt16",
        "access": "readwrite",
        "range": {"min": 0, "max": 150},
        "copydata": {"id": 6},
    },
    {"path": "Feed/Rate", "source": "ns=2;s=f", "type": "Double"},
]


def mapping(target: dict[str, Any] | None = None, **machine: Any) -> MachineMapping:
    data: dict[str, Any] = {
        "machine": "m1",
        "driver": {"endpoint": "opc.tcp://127.0.0.1:1"},
        "variables": VARIABLES,
        "copydata": {"targets": [target or {"name": "nest", "transport": "tcp-server", "port": 0}]},
    }
    data.update(machine)
    return MachineMapping.model_validate(data)


def copydata_sink(m: MachineMapping) -> CopydataSink:
    """The COPYDATA sink of a tree with this one machine."""
    return CopydataSink(VariableTree([m.definition()]), {m.machine: m})


def machine(target: dict[str, Any] | None = None, **kw: Any) -> Machine:
    tree = VariableTree([mapping(target, **kw).definition()])
    return tree.machines["m1"]


def ingest(m: Machine, path: str, value: Any, status: str = "Good") -> VariableNode:
    node = m.nodes[path]
    m.ingest(node, value, utcnow(), status)
    return node


class RecordingWriter:
    """The source side of a write, as the tree sees it: records what reaches the controller."""

    def __init__(self) -> None:
        self.writes: list[tuple[str, Any]] = []

    async def write(self, node: VariableNode, raw: Any) -> None:
        self.writes.append((node.path, raw))
