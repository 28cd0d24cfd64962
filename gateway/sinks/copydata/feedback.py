"""Replies from the nesting software: decoded with the target's layout, published, and optionally written.

Whatever comes back (over TCP, as UDP datagrams, or as WM_COPYDATA to the
gateway's window) is a frame in the same layout. Each one becomes:
- a log line (throttled: the peer decides how many it sends);
- an event on the tree's bus, channel `copydata/feedback`, which MQTT publishes
  as JSON on `<prefix>/<machine>/copydata/feedback`;
- the machine's `Status/CopydataFeedback` variable (the same JSON), for OPC UA.

With `accept_writes: true`, each item is also a write to the variable with that
id, through `Machine.write_node` like an OPC UA or MQTT write: read-only
variables, wrong types and values out of range are refused there, and the
outcome is logged and included in the published feedback. Items that do not
decode (unknown id, wrong size) are reported the same way; the stream itself
is intact, so the connection stays open.
"""

from __future__ import annotations

import json
import logging
import math
from datetime import datetime
from typing import Any

from gateway.codecs.copydata import CopydataError, Frame, Layout, VariableTable
from gateway.errors import RequestError
from gateway.model.context import WriteContext
from gateway.model.events import Event
from gateway.model.reach import reach
from gateway.model.tree import Machine, VariableNode
from gateway.sinks.copydata.status import CopydataStatus
from gateway.sinks.copydata.throttle import LogThrottle

log = logging.getLogger("gateway.sinks.copydata")

CHANNEL = "copydata/feedback"
ORIGIN = "copydata"
MAX_HEX = 256  # bytes of an undecodable item shown in the feedback


def plain(value: Any) -> Any:
    """A decoded value as JSON-ready data: DateTime as ISO text, non-finite floats as null."""
    if isinstance(value, float):
        return value if math.isfinite(value) else None
    if isinstance(value, datetime):
        return value.isoformat().replace("+00:00", "Z")
    if isinstance(value, list):
        return [plain(v) for v in value]
    return value


class Feedback:
    """Handles the frames one target's receivers send back."""

    def __init__(
        self,
        machine: Machine,
        target: str,
        table: VariableTable,
        by_id: dict[int, VariableNode],
        layout: Layout,
        status: CopydataStatus,
        *,
        accept_writes: bool = False,
        throttle: LogThrottle | None = None,
    ) -> None:
        self.machine = machine
        self.target = target
        self.name = f"{machine.name}/{target}"
        self.table = table
        self.by_id = by_id
        self.layout = layout
        self.status = status
        self.accept_writes = accept_writes
        self.throttle = throttle or LogThrottle(log)
        self.received = 0
        self.written = 0
        self.refused = 0

    def report_writers(self) -> None:
        """Say at start-up what replies may write, with which role, or that they are refused (no role)."""
        if not self.accept_writes:
            return
        access = self.machine.tree.access
        role = access.role_of(WriteContext(ORIGIN))
        if access.enabled and role is None:
            log.info(
                "copydata %s: accept_writes is on, but its writes are refused: they have no role "
                "(the gateway file's access.copydata_role)",
                self.name,
            )
            return
        opened = reach(self.machine, role, variables=self.by_id.values(), objects=(), alarms=False)
        log.info(
            "copydata %s: replies act as %s and may %s",
            self.name,
            role or "no role (access.enabled is false)",
            opened.what(),
        )

    async def handle(self, frame: Frame, peer: str) -> dict[str, Any]:
        """Decode, (write,) publish; returns the published document."""
        self.received += 1
        items = [self._item(index, item.id, item.data) for index, item in enumerate(frame.items)]
        if self.accept_writes:
            for entry in items:
                await self._write(entry, peer)
        for entry in items:
            entry.pop("_value", None)
        doc: dict[str, Any] = {"target": self.target, "peer": peer, "dwdata": frame.dwdata, "items": items}
        self.machine.tree.events.publish(Event(self.machine.name, CHANNEL, doc))
        self.status.feedback(json.dumps(doc, ensure_ascii=False, separators=(",", ":")))
        if not self.accept_writes:
            self.throttle.log(
                f"copydata {self.name} replies", logging.INFO, "copydata %s: reply from %s: %s",
                self.name, peer, _summary(items),
            )  # fmt: skip
        return doc

    def _item(self, index: int, vid: int, data: bytes) -> dict[str, Any]:
        entry: dict[str, Any] = {"id": vid}
        variable = self.table.get(vid)
        if variable is None:
            entry["error"] = f"id {vid} is not a variable of target {self.target}"
            entry["hex"] = data[:MAX_HEX].hex()
            return entry
        entry["path"] = variable.name
        try:
            value = variable.decode(data, self.layout)
        except CopydataError as exc:
            entry["error"] = str(exc)
            entry["hex"] = data[:MAX_HEX].hex()
            return entry
        entry["value"] = plain(value)
        entry["_value"] = value
        return entry

    async def _write(self, entry: dict[str, Any], peer: str) -> None:
        if "_value" not in entry:
            self.refused += 1
            entry["write"] = {"ok": False, "error": entry["error"], "status": "BadDecodingError"}
            self._log_refusal(peer, f"id {entry['id']}", entry["error"], "BadDecodingError")
            return
        node = self.by_id[entry["id"]]
        value = entry["_value"]
        try:
            await self.machine.write_node(node, value, WriteContext(ORIGIN, user=None))
        except RequestError as exc:
            self.refused += 1
            entry["write"] = {"ok": False, "error": exc.reason, "status": exc.status}
            self._log_refusal(peer, node.full_path, exc.reason, exc.status)
            return
        self.written += 1
        entry["write"] = {"ok": True}
        self.throttle.log(
            f"copydata {self.name} writes", logging.INFO, "copydata %s: %s wrote %s = %r",
            self.name, peer, node.full_path, value,
        )  # fmt: skip

    def _log_refusal(self, peer: str, what: str, reason: str, status: str) -> None:
        self.throttle.log(
            f"copydata {self.name} refusals", logging.WARNING,
            "copydata %s: write of %s from %s refused: %s (%s)", self.name, what, peer, reason, status,
        )  # fmt: skip


def _summary(items: list[dict[str, Any]]) -> str:
    parts = []
    for entry in items[:8]:
        if "error" in entry:
            parts.append(f"id {entry['id']}: {entry['error']}")
        else:
            parts.append(f"{entry['path']}={entry['value']!r}")
    if len(items) > 8:
        parts.append(f"… ({len(items)} items)")
    return ", ".join(parts)
