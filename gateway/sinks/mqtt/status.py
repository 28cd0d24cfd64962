"""Status documents: the gateway's liveness and each machine's connection, as retained JSON.

`<prefix>/status`: `{"state": "online", "version": …, "since": …, …}`, with a
last will saying `offline`. `<prefix>/<machine>/status`: the machine's
gateway-owned `Status/*` variables folded into one document,
`{"state": "connected", "reason": …, "since": …, "reconnects": n, "dropped": n, …}`.
Those variables are not published again one by one: one topic, one truth.
Status variables that other components add later appear under a snake_case key.
"""

from __future__ import annotations

import re
from datetime import datetime
from typing import Any

from gateway.model.tree import Machine, VariableNode
from gateway.sinks.mqtt.payloads import encode_document

# Status variable → document key. The state's own time is "since"; Connected repeats the state,
# and the MQTT link's own state means nothing to someone reading it over that link.
KEYS = {
    "Status/State": "state",
    "Status/LastError": "reason",
    "Status/ReconnectCount": "reconnects",
    "Status/MqttDropped": "dropped",
    "Status/MqttCoalesced": "coalesced",
    "Status/Endpoint": "endpoint",
}
# LastChange ticks every second while a machine runs: the values' own timestamps say the same, and a
# status topic that changes every second would drown the changes that matter.
SKIP = frozenset({"Status/Connected", "Status/MqttState", "Status/LastChange"})
CONNECTED = "connected"

_CAMEL = re.compile(r"(?<=[a-z0-9])(?=[A-Z])")


def snake(path: str) -> str:
    """`Status/Jobs/QueueLength` → `jobs_queue_length`."""
    parts = path.split("/")[1:]
    return "_".join(_CAMEL.sub("_", p).lower() for p in parts)


def machine_document(nodes: list[VariableNode]) -> dict[str, Any]:
    """The status document from a machine's Status/* nodes."""
    doc: dict[str, Any] = {"state": "unknown", "reason": "", "since": None, "reconnects": 0, "dropped": 0}
    state_ts: datetime | None = None
    for node in nodes:
        path = node.path
        if path in SKIP:
            continue
        sample = node.sample
        key = KEYS.get(path) or snake(path)
        doc[key] = sample.value
        if path == "Status/State":
            state_ts = sample.source_ts
    doc["since"] = state_ts
    if doc["state"] == CONNECTED:
        doc["reason"] = ""
    return doc


def machine_payload(nodes: list[VariableNode]) -> bytes:
    return encode_document(machine_document(nodes))


def status_nodes(machine: Machine) -> list[VariableNode]:
    return [n for n in machine.nodes.values() if n.internal and n.path.startswith("Status/")]


def gateway_online(version: str, since: datetime, machines: list[str], dropped: int) -> bytes:
    return encode_document(
        {"state": "online", "version": version, "since": since, "machines": machines, "dropped": dropped}
    )


def gateway_offline(version: str, reason: str, since: datetime | None = None) -> bytes:
    doc: dict[str, Any] = {"state": "offline", "version": version, "reason": reason}
    if since is not None:
        doc["since"] = since
    return encode_document(doc)
