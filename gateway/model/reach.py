"""What one role may change on a machine: the writes, method calls and alarm acknowledgements that the
access policy lets it make.

The doors nobody logs in at (anonymous OPC UA clients, MQTT writers, COPYDATA replies) report it
when they start, so that an open door is never a surprise. Methods that need no role (Programs.List,
Get) change nothing on the machine and are left out.
"""

from __future__ import annotations

from collections.abc import Collection, Iterable
from dataclasses import dataclass

from gateway.model.tree import Machine, VariableNode

LISTED = 8  # names shown per kind before "… and N more"


@dataclass(frozen=True, slots=True)
class Reach:
    machine: str
    writes: tuple[str, ...]  # variable paths
    calls: tuple[str, ...]  # Object.Method
    acknowledge: bool  # may acknowledge and confirm alarms

    def __bool__(self) -> bool:
        return bool(self.writes or self.calls or self.acknowledge)

    def what(self) -> str:
        """`write Feed/Override, Control/Start; call Commands.start; acknowledge alarms`."""
        parts = []
        if self.writes:
            parts.append("write " + _listed(self.writes))
        if self.calls:
            parts.append("call " + _listed(self.calls))
        if self.acknowledge:
            parts.append("acknowledge alarms")
        return "; ".join(parts) or "change nothing"

    def describe(self) -> str:
        """`laser-sim: write Feed/Override, …`."""
        return f"{self.machine}: {self.what()}"


def reach(
    machine: Machine,
    role: str | None,
    *,
    variables: Iterable[VariableNode] | None = None,
    objects: Collection[str] | None = None,
    alarms: bool = True,
) -> Reach:
    """What `role` may change on `machine` through a door that offers `variables` (default: all),
    the methods of `objects` (default: all) and, with `alarms`, acknowledging alarms."""
    policy = machine.tree.access
    nodes = machine.nodes.values() if variables is None else variables
    writes = tuple(
        node.path for node in nodes
        if not node.internal and node.definition.writable and policy.allows(role, machine.write_role(node))
    )  # fmt: skip
    calls = tuple(
        f"{method.object}.{method.name}" for method in machine.methods.values()
        if (objects is None or method.object in objects) and method.role is not None
        and policy.allows(role, method.role)
    )  # fmt: skip
    ack_role = machine.definition.acknowledge_role
    acknowledge = alarms and ack_role is not None and policy.allows(role, ack_role)
    return Reach(machine.name, writes, calls, acknowledge)


def _listed(names: tuple[str, ...]) -> str:
    shown = ", ".join(names[:LISTED])
    return shown if len(names) <= LISTED else f"{shown} and {len(names) - LISTED} more"
