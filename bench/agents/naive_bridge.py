"""The naive bridge, written the way most people write one first, as the baseline the gateway must beat.

An asyncua client subscription on the controller; for every data change, the
handler writes the value to the same variable of its own asyncua server with
`node.write_value`, then publishes it with paho (network thread via
`loop_start`) and waits for the broker's acknowledgement with `wait_for_publish`
before taking the next one. The subscription uses the same publishing interval
and queue size as the gateway's benchmark mapping, so that the two see the
same changes.
"""

from __future__ import annotations

import argparse
import asyncio
import contextlib
import json
import uuid
from pathlib import Path
from typing import Any

import paho.mqtt.client as paho
from asyncua import Client, Server, ua
from paho.mqtt.enums import CallbackAPIVersion

from bench.agents.protocol import serve, setup_logging

URI = "urn:bench:naive"
PER_FOLDER = 200


class Handler:
    def __init__(
        self, targets: dict[ua.NodeId, Any], topics: dict[ua.NodeId, str], mqtt: paho.Client
    ) -> None:
        self.targets = targets
        self.topics = topics
        self.mqtt = mqtt
        self.handled = 0

    async def datachange_notification(self, node: Any, val: Any, data: Any) -> None:
        await self.targets[node.nodeid].write_value(val)
        ts = data.monitored_item.Value.SourceTimestamp
        payload = json.dumps(
            {"value": val, "ts": ts.strftime("%Y-%m-%dT%H:%M:%S.%f")[:-3] + "Z", "quality": "good"}
        )
        self.mqtt.publish(self.topics[node.nodeid], payload, qos=1).wait_for_publish()
        self.handled += 1


async def main(args: argparse.Namespace) -> None:
    sources = [line.strip() for line in args.ids.read_text().splitlines() if line.strip()]
    server = Server()
    await server.init()
    server.set_endpoint(f"opc.tcp://127.0.0.1:{args.port}")
    server.set_security_policy([ua.SecurityPolicyType.NoSecurity])
    ns = await server.register_namespace(URI)
    root = await server.nodes.objects.add_folder(ua.NodeId("Naive", ns), ua.QualifiedName("Naive", ns))
    mirrors = []
    folder = root
    for i in range(len(sources)):
        if i % PER_FOLDER == 0:
            name = f"g{i // PER_FOLDER:03d}"
            folder = await root.add_folder(ua.NodeId(name, ns), ua.QualifiedName(name, ns))
        mirrors.append(
            await folder.add_variable(ua.NodeId(f"v{i:05d}", ns), ua.QualifiedName(f"v{i:05d}", ns), 0.0)
        )
    await server.start()

    mqtt = paho.Client(CallbackAPIVersion.VERSION2, client_id=f"naive-{uuid.uuid4().hex[:8]}")
    mqtt.connect("127.0.0.1", args.mqtt_port)
    mqtt.loop_start()

    client = Client(args.source, timeout=30)
    await client.connect()
    namespaces = await client.get_namespace_array()
    source_ids = []
    for text in sources:
        uri, ident = text.removeprefix("nsu=").split(";s=", 1)
        source_ids.append(ua.NodeId(ident, namespaces.index(uri), ua.NodeIdType.String))
    handler = Handler(
        dict(zip(source_ids, mirrors, strict=True)),
        {nid: f"naive/v{i:05d}" for i, nid in enumerate(source_ids)},
        mqtt,
    )
    subscription = await client.create_subscription(args.interval, handler)
    await subscription.subscribe_data_change(
        [client.get_node(nid) for nid in source_ids], queuesize=args.queue
    )

    def snap(request: dict[str, Any]) -> dict[str, Any]:
        return {"handled": handler.handled}

    try:
        await serve({"snap": snap}, {"endpoint": f"opc.tcp://127.0.0.1:{args.port}", "uri": URI})
    finally:
        with contextlib.suppress(Exception):  # a slow goodbye must not fail the benchmark
            async with asyncio.timeout(2):
                await client.disconnect()
        mqtt.loop_stop()
        await server.stop()


if __name__ == "__main__":
    parser = argparse.ArgumentParser()
    parser.add_argument("--source", required=True)
    parser.add_argument("--ids", type=Path, required=True)
    parser.add_argument("--port", type=int, required=True)
    parser.add_argument("--mqtt-port", type=int, required=True)
    parser.add_argument("--interval", type=float, default=10.0)
    parser.add_argument("--queue", type=int, default=10)
    setup_logging()
    asyncio.run(main(parser.parse_args()))
