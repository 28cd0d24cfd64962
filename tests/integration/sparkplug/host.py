"""A Sparkplug host application for the tests: a paho client in its own network thread.

It reads what the edge node publishes with tests/unit/codecs/sparkplug/host.py, a decoder written
from the specification that shares no code with the gateway's encoder (only the .proto's
generated classes), learns names and datatypes from the births as a host does, and can act as the
primary host (its STATE, with the will a host must set) and send NCMD and DCMD.
"""

from __future__ import annotations

import json
import threading
import time
import uuid
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import paho.mqtt.client as paho
from paho.mqtt.enums import CallbackAPIVersion

from gateway.codecs.sparkplug.sparkplug_b_pb2 import Payload
from tests.unit.codecs.sparkplug import host as spec
from tests.waiting import wait_until_sync

NAMESPACE = "spBv1.0"
REBIRTH = "Node Control/Rebirth"


@dataclass
class Seen:
    """One message the host received, decoded."""

    topic: str
    kind: str  # NBIRTH, DDATA, …
    device: str | None
    payload: spec.HostPayload
    raw: bytes
    received: float  # time.time()
    names: dict[int, str]  # alias → name, as the births of the session so far said

    @property
    def seq(self) -> int | None:
        return self.payload.seq

    def metric(self, name: str) -> spec.HostMetric | None:
        for m in self.payload.metrics:
            if (m.name or self.names.get(m.alias or -1)) == name:
                return m
        return None

    def values(self) -> list[tuple[str, Any, int | None, bool]]:
        """(name, value, timestamp, historical) of every metric, names resolved through the births."""
        return [
            (
                m.name or self.names.get(m.alias if m.alias is not None else -1, f"alias {m.alias}"),
                m.value,
                m.timestamp,
                m.is_historical,
            )
            for m in self.payload.metrics
        ]


@dataclass
class SparkplugHost:
    port: int
    group: str = "cnc"
    host_id: str | None = None  # a primary host: STATE online when it connects, its will offline
    online: bool = True  # with host_id: the STATE it publishes at connect
    persistent: bool = False  # a session the broker keeps (with queue_qos0_messages: nothing lost while away)
    client_id: str = field(default_factory=lambda: f"host-{uuid.uuid4().hex[:8]}")
    messages: list[Seen] = field(default_factory=list)
    subscribed: threading.Event = field(default_factory=threading.Event)
    state_ts: int = 0
    _will_ts: int = 0
    connects: int = 0
    _types: dict[Any, int] = field(default_factory=dict)  # alias or name → datatype, from the births
    _names: dict[int, str] = field(default_factory=dict)
    _lock: threading.Lock = field(default_factory=threading.Lock)
    client: paho.Client | None = None

    def start(self) -> SparkplugHost:
        client = paho.Client(
            CallbackAPIVersion.VERSION2, client_id=self.client_id, clean_session=not self.persistent
        )
        client.on_connect = self._on_connect
        client.on_message = self._on_message
        client.on_subscribe = lambda *a: self.subscribed.set()
        client.reconnect_delay_set(0.05, 0.2)
        self.client = client
        self._set_will()
        client.connect("127.0.0.1", self.port, keepalive=10)
        client.loop_start()
        wait_until_sync(self.subscribed.is_set, timeout=10, message="the host's SUBACK")
        return self

    def _set_will(self) -> None:
        """The will of the next CONNECT: offline, with the timestamp that session's online STATE repeats."""
        if self.host_id is None or self.client is None:
            return
        self._will_ts = self._next_ts()
        self.client.will_set(
            self.state_topic, json.dumps({"online": False, "timestamp": self._will_ts}), 1, True
        )

    def _next_ts(self) -> int:
        self.state_ts = max(self.state_ts + 1, int(time.time() * 1000))
        return self.state_ts

    @property
    def state_topic(self) -> str:
        return f"{NAMESPACE}/STATE/{self.host_id}"

    def _on_connect(self, client: paho.Client, userdata: Any, flags: Any, reason: Any, props: Any) -> None:
        if reason.is_failure:
            return
        self.connects += 1
        if not (self.persistent and flags.session_present):
            client.subscribe([(f"{NAMESPACE}/{self.group}/#", 1)])
        if self.host_id is not None and self.online:
            self._state(True, self._will_ts)
        self._set_will()  # the next CONNECT's (paho sends the will it holds at connect time)

    def publish_state(self, online: bool) -> None:
        """Go online or offline as a host does, with a newer timestamp."""
        assert self.host_id is not None
        self.online = online
        self._state(online, self._next_ts())

    def _state(self, online: bool, ts: int) -> None:
        assert self.client is not None
        self.client.publish(self.state_topic, json.dumps({"online": online, "timestamp": ts}), 1, True)

    def _on_message(self, client: paho.Client, userdata: Any, msg: paho.MQTTMessage) -> None:
        received = time.time()
        parts = msg.topic.split("/")
        if len(parts) < 4 or parts[0] != NAMESPACE or parts[1] != self.group:
            return
        kind = parts[2]
        if kind in ("NCMD", "DCMD"):
            return  # our own commands
        device = parts[4] if len(parts) > 4 else None
        raw = bytes(msg.payload)
        with self._lock:
            if kind in ("NBIRTH", "DBIRTH"):
                birth = Payload.FromString(raw)
                for m in birth.metrics:
                    if m.HasField("alias"):
                        self._types[m.alias] = m.datatype
                        self._names[m.alias] = m.name
                    self._types[m.name] = m.datatype
            payload = spec.read(raw, self._types)
            self.messages.append(Seen(msg.topic, kind, device, payload, raw, received, dict(self._names)))

    def stop(self) -> None:
        if self.client is not None:
            self.client.disconnect()
            self.client.loop_stop()
            self.client = None

    # --- reading ----------------------------------------------------------------------------------

    def of(self, kind: str, device: str | None = None) -> list[Seen]:
        with self._lock:
            return [s for s in self.messages if s.kind == kind and (device is None or s.device == device)]

    def last(self, kind: str, device: str | None = None) -> Seen | None:
        got = self.of(kind, device)
        return got[-1] if got else None

    def since(self, mark: int) -> list[Seen]:
        with self._lock:
            return self.messages[mark:]

    def count(self) -> int:
        with self._lock:
            return len(self.messages)

    def value(self, device: str, name: str) -> Any:
        """The metric's latest value as a host shows it: from the last birth and the live DDATA after it."""
        found: Any = None
        with self._lock:
            messages = list(self.messages)
        for seen in messages:
            if seen.device != device or seen.kind not in ("DBIRTH", "DDATA"):
                continue
            for name_, value, _, historical in seen.values():
                if name_ == name and not historical:
                    found = value
        return found

    def quality(self, device: str, name: str) -> int | None:
        """The metric's Quality as a host tracks it: from its birth, then each live DDATA that changes it."""
        found: int | None = None
        with self._lock:
            messages = list(self.messages)
        for seen in messages:
            if seen.device != device or seen.kind not in ("DBIRTH", "DDATA"):
                continue
            metric = seen.metric(name)
            if metric is not None and not metric.is_historical and "Quality" in metric.properties:
                found = metric.properties["Quality"][1]
        return found

    def wait(self, condition: Callable[[], Any], timeout: float = 15.0, message: str = "a message") -> Any:
        return wait_until_sync(condition, timeout=timeout, message=message)

    # --- commands ----------------------------------------------------------------------------------

    def alias(self, device: str, name: str) -> int:
        birth = self.last("DBIRTH", device)
        assert birth is not None, f"no DBIRTH of {device} yet"
        for m in birth.payload.metrics:
            if m.name == name:
                assert m.alias is not None
                return m.alias
        raise KeyError(name)

    def datatype(self, device: str, name: str) -> int:
        birth = self.last("DBIRTH", device)
        assert birth is not None
        for m in birth.payload.metrics:
            if m.name == name and m.datatype is not None:
                return m.datatype
        raise KeyError(name)

    def rebirth(self, edge_node: str = "cnc-gateway") -> None:
        self.send(
            f"{NAMESPACE}/{self.group}/NCMD/{edge_node}",
            spec.command(spec.write(True, spec.BOOLEAN, name=REBIRTH)),
        )

    def write(self, device: str, name: str, value: Any, edge_node: str = "cnc-gateway") -> None:
        """A DCMD writing `value` to the metric, by alias, as a host does."""
        metric = spec.write(value, self.datatype(device, name), alias=self.alias(device, name))
        self.send(f"{NAMESPACE}/{self.group}/DCMD/{edge_node}/{device}", spec.command(metric))

    def send(self, topic: str, payload: bytes, retain: bool = False) -> None:
        assert self.client is not None
        self.client.publish(topic, payload, 0, retain)
