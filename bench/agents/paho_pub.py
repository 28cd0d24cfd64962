"""The paho ceiling: one paho client publishing 80-byte payloads to Mosquitto as fast as it can.

The payload imitates the gateway's JSON (value, ts, quality, padded to 80 bytes),
so that the same subscriber measures both. QoS 1 keeps a window of 200 messages in
flight, like the gateway's default `max_inflight`. The network loop runs in the
publishing thread (no paho thread), as in the gateway.
"""

from __future__ import annotations

import argparse
import time
import uuid
from datetime import UTC, datetime
from typing import Any

import paho.mqtt.client as paho
from paho.mqtt.enums import CallbackAPIVersion, MQTTErrorCode

from bench.agents.protocol import serve_in_thread, setup_logging

PAYLOAD_SIZE = 80
TOPICS = 1000
BURST = 100


def payload(seq: int, ts: str) -> bytes:
    head = f'{{"value":{float(seq)!r},"ts":"{ts}","quality":"good","pad":"'
    return (head + "x" * max(0, PAYLOAD_SIZE - len(head) - 2) + '"}').encode()


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("--port", type=int, required=True)
    parser.add_argument("--qos", type=int, default=0)
    args = parser.parse_args()
    setup_logging()
    client = paho.Client(CallbackAPIVersion.VERSION2, client_id=f"bench-pub-{uuid.uuid4().hex[:8]}")
    client.max_inflight_messages_set(200)
    client.max_queued_messages_set(1000)
    connected: list[bool] = []
    client.on_connect = lambda *a: connected.append(True)
    client.connect("127.0.0.1", args.port, keepalive=60)
    while not connected:
        client.loop(timeout=0.05)
    topics = [f"raw/t{i:04d}" for i in range(TOPICS)]
    state = {"seq": 0}

    def run(request: dict[str, Any]) -> dict[str, Any]:
        seconds = float(request["seconds"])
        qos = args.qos
        seq = state["seq"]
        start = time.perf_counter()
        end = start + seconds
        published = 0
        while time.perf_counter() < end:
            ts = datetime.now(UTC).isoformat(timespec="milliseconds").replace("+00:00", "Z")
            for _ in range(BURST):
                seq += 1
                data = payload(seq, ts)
                while client.publish(topics[seq % TOPICS], data, qos).rc == MQTTErrorCode.MQTT_ERR_QUEUE_SIZE:
                    client.loop(timeout=0.001)
                published += 1
            client.loop(timeout=0)
            while client.want_write():
                client.loop(timeout=0.01)
        state["seq"] = seq
        return {"published": published, "elapsed": time.perf_counter() - start}

    def snap(request: dict[str, Any]) -> dict[str, Any]:
        client.loop(timeout=0)
        return {"published": state["seq"]}

    thread = serve_in_thread({"run": run, "snap": snap}, lambda: None)
    thread.join()
    client.disconnect()


if __name__ == "__main__":
    main()
