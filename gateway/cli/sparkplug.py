"""`cnc-gateway sparkplug watch`: a small Sparkplug B host that prints what edge nodes publish, decoded.

It subscribes to `spBv1.0/<group>/#`, learns each metric's name and datatype from the births (aliases are
per edge node), and prints one line per message: births with their metric count (every metric with
`--metrics`), DDATA/NDATA as `name=value` pairs, deaths with their bdSeq or timestamp. `--rebirth` asks
every edge node it has not seen born (and, at start, the one named by `--edge-node`) for its births, as
a host application does when it joins late. What it uses is the gateway's own codec and MQTT adapter;
for a host that shares no code with the gateway, use Ignition's MQTT Engine or the tests' host.
"""

from __future__ import annotations

import argparse
import asyncio
import logging
import sys
import time
import uuid
from dataclasses import dataclass, field
from datetime import UTC, datetime
from typing import Any

from gateway.app import run_until_signalled
from gateway.codecs.sparkplug import (
    BDSEQ,
    REBIRTH,
    MessageType,
    Metric,
    SparkplugError,
    SparkplugType,
    Topic,
    encode_command,
    gateway_type,
    get_metric_value,
    node_topic,
    parse_payload,
    parse_topic,
)
from gateway.codecs.sparkplug.sparkplug_b_pb2 import Payload
from gateway.errors import BrokerError
from gateway.model.types import TypeSpec
from gateway.sinks.mqtt_link.client import BrokerSettings, Incoming, MqttClient

SHOWN = 12  # name=value pairs printed per data message unless --all
RETRY_EVERY = 1.0  # s between connection attempts


def register(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    p = sub.add_parser("sparkplug", help="Sparkplug B tools: watch what edge nodes publish")
    actions = p.add_subparsers(dest="sparkplug_command", metavar="ACTION", required=True)
    q = actions.add_parser("watch", help="print births, data and deaths of a group's edge nodes, decoded")
    q.add_argument("--host", default="127.0.0.1", help="MQTT broker (default 127.0.0.1)")
    q.add_argument("--port", type=int, default=1883, help="MQTT broker port (default 1883)")
    q.add_argument("--group", default="cnc", help="Sparkplug group id (default cnc)")
    q.add_argument("--edge-node", default="cnc-gateway", help="edge node to ask for its births (--rebirth)")
    q.add_argument(
        "--rebirth", action="store_true", help="ask for births (NCMD Node Control/Rebirth) to learn names"
    )
    q.add_argument("--metrics", action="store_true", help="print every metric of a birth")
    q.add_argument(
        "--all", action="store_true", help=f"print every metric of a data message (default {SHOWN})"
    )
    q.add_argument("--count", type=int, default=None, help="stop after this many messages")
    q.set_defaults(handler=handle_watch)


@dataclass
class Node:
    """What the births of one edge node said: alias → (name, type)."""

    metrics: dict[int, tuple[str, TypeSpec | None]] = field(default_factory=dict)
    born: bool = False


class Watcher:
    def __init__(self, args: argparse.Namespace, out: Any = sys.stdout) -> None:
        self.args = args
        self.out = out
        self.nodes: dict[str, Node] = {}
        self.seen = 0
        self.done = asyncio.Event()
        self.client: MqttClient | None = None
        self._asked: set[str] = set()

    def on_message(self, msg: Incoming) -> None:
        try:
            topic = parse_topic(msg.topic)
        except SparkplugError:
            return
        if not isinstance(topic, Topic) or topic.message_type in (MessageType.NCMD, MessageType.DCMD):
            return
        where = topic.edge_node_id + (f"/{topic.device_id}" if topic.device_id else "")
        try:
            payload = parse_payload(msg.payload)
        except SparkplugError as exc:
            self.print(f"{topic.message_type.value:7} {where}  {exc}")
            return
        node = self.nodes.setdefault(topic.edge_node_id, Node())
        kind = topic.message_type
        if kind in (MessageType.NBIRTH, MessageType.DBIRTH):
            if kind is MessageType.NBIRTH:
                node.born = True
            for m in payload.metrics:
                if m.HasField("alias"):
                    node.metrics[m.alias] = (m.name, _spec(m.datatype))
        elif not node.born and self.args.rebirth:
            self.ask_rebirth(topic.edge_node_id)
        self.print(self.describe(kind, where, payload, node))
        self.seen += 1
        if self.args.count is not None and self.seen >= self.args.count:
            self.done.set()

    def describe(self, kind: MessageType, where: str, payload: Payload, node: Node) -> str:
        seq = f"seq {payload.seq:<3}  " if payload.HasField("seq") else ""
        head = f"{kind.value:7} {where}  {seq}"
        if kind is MessageType.NDEATH:
            number = next((m.long_value for m in payload.metrics if m.name == BDSEQ), None)
            return f"{head}bdSeq {number}"
        if kind is MessageType.DDEATH:
            return f"{head}(device offline)"
        if kind in (MessageType.NBIRTH, MessageType.DBIRTH):
            bdseq = next((f"bdSeq {m.long_value}  " for m in payload.metrics if m.name == BDSEQ), "")
            lines = [f"{head}{bdseq}{len(payload.metrics)} metrics"]
            if self.args.metrics:
                for m in payload.metrics:
                    kind_text = _type_name(m.datatype) + (f", alias {m.alias}" if m.HasField("alias") else "")
                    lines.append(f"    {m.name} = {self.value(m, _spec(m.datatype))}  ({kind_text})")
            return "\n".join(lines)
        pairs = []
        for m in payload.metrics:
            name, spec = (
                node.metrics.get(m.alias, (f"alias {m.alias}", None))
                if m.HasField("alias")
                else (m.name, None)
            )
            flag = " (historical)" if m.is_historical else ""
            quality = ""
            for key, prop in zip(m.properties.keys, m.properties.values, strict=False):
                if key == "Quality":
                    quality = {0: " BAD", 192: "", 500: " STALE"}.get(
                        prop.int_value, f" quality {prop.int_value}"
                    )
            pairs.append(f"{name}={self.value(m, spec)}{quality}{flag}")
        shown = pairs if self.args.all else pairs[:SHOWN]
        more = f" … and {len(pairs) - len(shown)} more" if len(pairs) > len(shown) else ""
        return head + ", ".join(shown) + more

    @staticmethod
    def value(m: Payload.Metric, spec: TypeSpec | None) -> str:
        if m.is_null:
            return "null"
        if spec is None:
            return f"<{m.WhichOneof('value') or 'no value'}>"
        try:
            value = get_metric_value(m, spec)
        except SparkplugError as exc:
            return f"<{exc}>"
        if isinstance(value, datetime):
            return value.isoformat(timespec="milliseconds")
        if isinstance(value, list) and len(value) > 8:
            return f"[{', '.join(map(repr, value[:8]))}, … {len(value)} values]"
        return repr(value)

    def print(self, text: str) -> None:
        stamp = datetime.now(UTC).astimezone().strftime("%H:%M:%S.%f")[:-3]
        print(f"{stamp}  {text}", file=self.out, flush=True)

    def connected(self, client: MqttClient) -> None:
        self.client = client
        self._asked.clear()
        if self.args.rebirth:
            self.ask_rebirth(self.args.edge_node)

    def ask_rebirth(self, edge_node: str) -> None:
        if edge_node in self._asked or self.client is None:
            return
        self._asked.add(edge_node)
        now = int(time.time() * 1000)
        payload = encode_command([Metric(REBIRTH, TypeSpec.parse("Boolean"), True, now)], timestamp=now)
        try:
            self.client.publish(node_topic(self.args.group, MessageType.NCMD, edge_node), payload, 0, False)
        except BrokerError as exc:
            print(f"cannot ask {edge_node} for a rebirth: {exc.reason}", file=sys.stderr)


async def watch(args: argparse.Namespace, watcher: Watcher | None = None) -> None:
    watcher = watcher or Watcher(args)
    lost = asyncio.Event()
    settings = BrokerSettings(args.host, args.port, f"cnc-gateway-watch-{uuid.uuid4().hex[:8]}")
    print(
        f"watching spBv1.0/{args.group}/# on mqtt://{args.host}:{args.port} (Ctrl-C stops)", file=sys.stderr
    )
    while not watcher.done.is_set():
        client = MqttClient(
            settings,
            on_message=watcher.on_message,
            on_published=lambda mid: None,
            on_lost=lambda reason: lost.set(),
        )
        try:
            await client.connect()
        except BrokerError as exc:
            print(f"{exc.reason}; retrying", file=sys.stderr)
            await asyncio.sleep(RETRY_EVERY)
            continue
        client.subscribe([f"spBv1.0/{args.group}/#"], qos=0)
        watcher.connected(client)
        lost.clear()
        stop = asyncio.ensure_future(watcher.done.wait())
        gone = asyncio.ensure_future(lost.wait())
        await asyncio.wait({stop, gone}, return_when=asyncio.FIRST_COMPLETED)
        stop.cancel()
        gone.cancel()
        if watcher.done.is_set():
            await client.disconnect()
        else:
            print("connection lost; reconnecting", file=sys.stderr)
            await asyncio.sleep(RETRY_EVERY)


def _spec(datatype: int) -> TypeSpec | None:
    """The gateway type of a Sparkplug datatype number (None: one the gateway has no type for)."""
    try:
        return gateway_type(SparkplugType(datatype))
    except ValueError:
        return None


def _type_name(datatype: int) -> str:
    try:
        return SparkplugType(datatype).name
    except ValueError:
        return f"datatype {datatype}"


def handle_watch(args: argparse.Namespace) -> int:
    logging.basicConfig(level=logging.WARNING, format="%(levelname)s %(message)s")
    asyncio.run(run_until_signalled(watch(args)))
    return 0
