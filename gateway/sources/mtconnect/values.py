"""MTConnect observations into tree values: text to the variable's type, conditions to their active list.

Shared by both ways in (an agent, an SHDR adapter). An observation of UNAVAILABLE is a
Bad sample (`BadDataUnavailable`, with the reason), text that does not fit the variable's
type a `BadTypeMismatch` one; the rest goes to `Machine.ingest` in the controller's type,
so the mapping's scaling applies as for any driver. A CONDITION data item is kept as its
list of active Warnings and Faults (gateway/codecs/mtconnect/conditions.py) in a String[]
variable, its worst level in a String one, or whether a Fault is active in a Boolean.
"""

from __future__ import annotations

import logging
from datetime import datetime
from typing import Any

from gateway.codecs.mtconnect.conditions import ActiveCondition, format_condition_text
from gateway.codecs.mtconnect.timestamps import parse_timestamp
from gateway.model.tree import Machine, VariableNode
from gateway.model.types import DataType, TypeSpec

log = logging.getLogger("gateway.sources.mtconnect")

UNAVAILABLE_STATUS = "BadDataUnavailable"
TRUE = frozenset({"true", "1", "yes", "on", "active"})
FALSE = frozenset({"false", "0", "no", "off", "inactive"})
_INTEGERS = frozenset(
    {DataType.SBYTE, DataType.BYTE, DataType.INT16, DataType.UINT16, DataType.INT32, DataType.UINT32,
     DataType.INT64, DataType.UINT64}
)  # fmt: skip


class Mismatch(ValueError):
    pass


def _scalar(base: DataType, text: str) -> Any:
    if base is DataType.STRING:
        return text
    if base in (DataType.DOUBLE, DataType.FLOAT):
        try:
            return float(text)
        except ValueError:
            raise Mismatch(f"{text[:40]!r} is not a number") from None
    if base in _INTEGERS:
        try:
            return int(text)
        except ValueError:
            try:
                number = float(text)
            except ValueError:
                raise Mismatch(f"{text[:40]!r} is not an integer") from None
            if not number.is_integer():
                raise Mismatch(f"{text[:40]!r} is not an integer") from None
            return int(number)
    if base is DataType.BOOLEAN:
        word = text.strip().lower()
        if word in TRUE:
            return True
        if word in FALSE:
            return False
        raise Mismatch(f"{text[:40]!r} is not a truth value (true/false, 1/0, ON/OFF)")
    if base is DataType.DATETIME:
        stamp = parse_timestamp(text.strip())
        if stamp is None:
            raise Mismatch(f"{text[:40]!r} is not an ISO 8601 time")
        return stamp
    raise Mismatch(f"{base.value} is not a type MTConnect values convert to")


def convert(spec: TypeSpec, text: str) -> Any:
    """`text` as a value of `spec` (arrays: space-separated). Raises Mismatch."""
    if spec.array:
        return [_scalar(spec.base, part) for part in text.split()]
    return _scalar(spec.base, text)


class Ingest:
    """Puts observations of one machine's mapped data items into the tree."""

    def __init__(self, machine: Machine, where: str) -> None:
        self.machine = machine
        self.where = where  # "the agent" / "the adapter": in reasons
        self.conditions: dict[VariableNode, dict[str, ActiveCondition]] = {}
        self.mismatches = 0
        self.held: dict[VariableNode, tuple[Any, datetime, str, str]] = {}  # the last of each, as ingested
        self._said: set[VariableNode] = set()

    def put(self, node: VariableNode, raw: Any, ts: datetime, status: str = "Good", reason: str = "") -> None:
        self.held[node] = (raw, ts, status, reason)
        self.machine.ingest(node, raw, ts, status, reason)

    def restore(self) -> None:
        """The values as they were before the connection dropped (a resumed stream brings the changes)."""
        for node, (raw, ts, status, reason) in self.held.items():
            self.machine.ingest(node, raw, ts, status, reason)

    def forget(self) -> None:
        self.held.clear()
        self.conditions.clear()

    def value(self, node: VariableNode, text: str, ts: datetime) -> None:
        if text == "UNAVAILABLE":
            self.put(node, None, ts, UNAVAILABLE_STATUS, f"UNAVAILABLE at {self.where}")
            return
        try:
            raw = convert(node.definition.raw_type, text)
        except Mismatch as exc:
            self.mismatches += 1
            reason = f"{self.where} sent {exc}; the mapping says {node.definition.raw_type}"
            if node not in self._said:
                self._said.add(node)
                log.warning("%s: %s: %s", self.machine.name, node.path, reason)
            self.put(node, None, ts, "BadTypeMismatch", reason)
            return
        self.put(node, raw, ts)

    def condition(
        self,
        node: VariableNode,
        level: str,
        ts: datetime,
        active: ActiveCondition | None,
        *,
        replace: bool = False,
    ) -> None:
        """One condition observation (NORMAL, WARNING, FAULT, UNAVAILABLE); `replace` starts a snapshot."""
        if level == "UNAVAILABLE":
            self.conditions.pop(node, None)
            self.put(node, None, ts, UNAVAILABLE_STATUS, f"UNAVAILABLE at {self.where}")
            return
        held = {} if replace else self.conditions.setdefault(node, {})
        self.conditions[node] = held
        if level == "NORMAL":
            key = active.key if active is not None and (active.condition_id or active.native_code) else None
            if key is None:
                held.clear()
            else:
                held.pop(key, None)
        elif active is not None:
            held[active.key] = active
        self.publish(node, ts)

    def publish(self, node: VariableNode, ts: datetime) -> None:
        held = self.conditions.get(node, {})
        spec = node.definition.raw_type
        value: Any
        if spec.array:
            value = [format_condition_text(c) for c in held.values()]
        elif spec.base is DataType.BOOLEAN:
            value = any(c.level == "FAULT" for c in held.values())
        else:
            levels = {c.level for c in held.values()}
            value = "FAULT" if "FAULT" in levels else "WARNING" if levels else "NORMAL"
        self.put(node, value, ts)
