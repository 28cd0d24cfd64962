"""Consumers for the slow-consumer drill: three that stall, and readers that keep count.

The stalled ones are what a hung dashboard, a frozen SCADA client and a nesting
package stuck in a modal dialog look like on the wire:
- `stalled_mqtt`: a raw TCP socket that connects, subscribes to everything at
  QoS 1, reads its SUBACK, and then never reads again (no keepalive, so the broker
  keeps it);
- `StalledOpcUa`: a session that creates a subscription with monitored items on
  every variable (queue size 0: "as many as the server allows", what asyncua's
  own `subscribe_data_change` asks for) and never sends a Publish request;
- `stalled_copydata`: a TCP client of a tcp-server target that never reads.
"""

from __future__ import annotations

import asyncio
import contextlib
import json
import socket
import struct
import threading
import uuid
from typing import Any

import paho.mqtt.client as paho
from asyncua import ua
from paho.mqtt.enums import CallbackAPIVersion

from gateway.codecs.copydata import FrameDecoder
from tests.opcua_client import Client

SMALL_BUFFER = 4096  # bytes of kernel receive buffer: the stall shows at once


def _mqtt_string(text: str) -> bytes:
    data = text.encode()
    return struct.pack("!H", len(data)) + data


def _mqtt_packet(kind: int, body: bytes) -> bytes:
    length, encoded = len(body), bytearray()
    while True:
        byte, length = length % 128, length // 128
        encoded.append(byte | (0x80 if length else 0))
        if not length:
            break
    return bytes([kind]) + bytes(encoded) + body


def stalled_mqtt(port: int, topic: str = "#", client_id: str = "drill-stalled") -> socket.socket:
    """CONNECT (MQTT 3.1.1, clean session, keepalive 0), SUBSCRIBE `topic` at QoS 1, read up to the
    SUBACK; then the socket is returned unread, for the caller to keep open and ignore."""
    sock = socket.socket()
    sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, SMALL_BUFFER)
    sock.settimeout(10)
    sock.connect(("127.0.0.1", port))
    sock.sendall(
        _mqtt_packet(0x10, _mqtt_string("MQTT") + bytes([4, 0x02]) + b"\x00\x00" + _mqtt_string(client_id))
    )
    connack = _read_exactly(sock, 4)
    if connack[0] != 0x20 or connack[3] != 0:
        raise RuntimeError(f"the broker refused the stalled subscriber: {connack.hex()}")
    sock.sendall(_mqtt_packet(0x82, b"\x00\x01" + _mqtt_string(topic) + b"\x01"))
    while True:  # retained messages may follow the SUBACK at once; read only up to it
        first = _read_exactly(sock, 1)
        length, shift = 0, 0
        while True:
            byte = _read_exactly(sock, 1)[0]
            length |= (byte & 0x7F) << shift
            shift += 7
            if not byte & 0x80:
                break
        body = _read_exactly(sock, length)
        if first[0] & 0xF0 == 0x90:
            if body[2] != 0x01:
                raise RuntimeError(f"the broker did not grant QoS 1: {body.hex()}")
            return sock


def _read_exactly(sock: socket.socket, n: int) -> bytes:
    data = b""
    while len(data) < n:
        chunk = sock.recv(n - len(data))
        if not chunk:
            raise ConnectionError("the broker closed the connection")
        data += chunk
    return data


def stalled_copydata(port: int) -> socket.socket:
    sock = socket.socket()
    sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, SMALL_BUFFER)
    sock.connect(("127.0.0.1", port))
    return sock


def _no_publish_loop() -> None:
    """Replaces asyncua's publish loop starter: this client never asks for its notifications."""


class StalledOpcUa:
    """A session whose subscription watches every variable of the gateway and is never served."""

    def __init__(self, endpoint: str) -> None:
        self.client = Client(endpoint, timeout=10)
        self.items = 0
        self.revised_queue = 0

    async def start(self, node_ids: list[ua.NodeId], publishing_interval: float = 100.0) -> StalledOpcUa:
        await self.client.connect()
        session = self.client.uaclient.session
        session.ensure_publish_loop = _no_publish_loop  # type: ignore[method-assign]
        params = ua.CreateSubscriptionParameters(
            RequestedPublishingInterval=publishing_interval, RequestedLifetimeCount=10_000,
            RequestedMaxKeepAliveCount=3_000, MaxNotificationsPerPublish=0, PublishingEnabled=True,
            Priority=0,
        )  # fmt: skip
        result = await session.create_subscription(params, callback=lambda *_: None)
        requests = [
            ua.MonitoredItemCreateRequest(
                ItemToMonitor=ua.ReadValueId(NodeId=node_id, AttributeId=ua.AttributeIds.Value),
                MonitoringMode=ua.MonitoringMode.Reporting,
                RequestedParameters=ua.MonitoringParameters(
                    ClientHandle=handle, SamplingInterval=0, QueueSize=0, DiscardOldest=True
                ),
            )
            for handle, node_id in enumerate(node_ids, start=1)
        ]
        created = await session.create_monitored_items(
            ua.CreateMonitoredItemsParameters(
                SubscriptionId=result.SubscriptionId, TimestampsToReturn=ua.TimestampsToReturn.Both,
                ItemsToCreate=requests,
            )
        )  # fmt: skip
        good = [r for r in created if r.StatusCode.is_good()]
        self.items = len(good)
        self.revised_queue = max((r.RevisedQueueSize for r in good), default=0)
        return self

    async def stop(self) -> None:
        with contextlib.suppress(Exception):  # a server that dropped the session already
            await self.client.disconnect()


class CopydataReader:
    """A tcp-server target's client that reads everything; keeps the newest noise sequence number seen."""

    def __init__(self, doubles: set[int]) -> None:
        self.doubles = doubles  # variable ids whose values are noise sequence numbers (Double)
        self.frames = 0
        self.newest = 0.0
        self._task: asyncio.Task[None] | None = None

    async def connect(self, port: int) -> CopydataReader:
        reader, self._writer = await asyncio.open_connection("127.0.0.1", port)
        self._task = asyncio.create_task(self._read(reader), name="drill:copydata-reader")
        return self

    async def _read(self, reader: asyncio.StreamReader) -> None:
        decoder = FrameDecoder()
        while data := await reader.read(65536):
            for frame in decoder.feed(data):
                self.frames += 1
                for item in frame.items:
                    if item.id in self.doubles and len(item.data) == 8:
                        self.newest = max(self.newest, struct.unpack("<d", item.data)[0])

    async def close(self) -> None:
        self._writer.close()
        if self._task is not None:
            self._task.cancel()
            await asyncio.gather(self._task, return_exceptions=True)


class OpcUaCounter:
    """Subscription handler: notifications received, and the newest noise sequence number among them."""

    def __init__(self) -> None:
        self.notifications = 0
        self.newest = 0.0

    def datachange_notification(self, node: Any, val: Any, data: Any) -> None:
        self.notifications += 1
        if isinstance(val, float):
            self.newest = max(self.newest, val)


class SequenceSubscriber:
    """A normal MQTT subscriber (QoS 1, its own network thread) keeping the noise sequence numbers it got."""

    def __init__(self, port: int, topic: str) -> None:
        self.port = port
        self.topic = topic
        self.seen: set[int] = set()
        self.messages = 0
        self.newest = 0
        self._lock = threading.Lock()
        self._subscribed = threading.Event()
        self._client = paho.Client(CallbackAPIVersion.VERSION2, client_id=f"drill-{uuid.uuid4().hex[:8]}")
        self._client.on_connect = lambda c, *_: c.subscribe(self.topic, 1)
        self._client.on_subscribe = lambda *_: self._subscribed.set()
        self._client.on_message = self._on_message

    def start(self) -> SequenceSubscriber:
        self._client.connect("127.0.0.1", self.port, keepalive=30)
        self._client.loop_start()
        if not self._subscribed.wait(10):
            raise RuntimeError("no SUBACK for the sequence subscriber")
        return self

    def _on_message(self, client: Any, userdata: Any, msg: paho.MQTTMessage) -> None:
        value = json.loads(msg.payload).get("value")
        with self._lock:
            self.messages += 1
            if isinstance(value, float) and value.is_integer():
                seq = int(value)
                self.seen.add(seq)
                self.newest = max(self.newest, seq)

    def missing(self, first: int, last: int) -> int:
        with self._lock:
            return sum(1 for seq in range(first, last + 1) if seq not in self.seen)

    def stop(self) -> None:
        self._client.disconnect()
        self._client.loop_stop()
