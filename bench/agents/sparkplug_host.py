"""A Sparkplug B host (paho, its own process) that counts DDATA metrics, measures their latency, watches seq.

What it decodes, with the generated protobuf classes only (not the gateway's codec): DBIRTHs (alias →
name), DDATA (each metric a change; its value the noise sequence number, a Double; latency = receipt
time minus the metric's timestamp, which is the source timestamp in ms), NBIRTH/NDEATH (sessions).
`seq` is checked over every message of a session (NBIRTH starts at 0). `rebirth` publishes an NCMD
`Node Control/Rebirth` and answers with the time until the NBIRTH and every DBIRTH are in. DDATA of
an edge node born before the host listened makes it ask for a rebirth once, as hosts do.
"""

from __future__ import annotations

import argparse
import threading
import time
import uuid
from typing import Any

import paho.mqtt.client as paho
from paho.mqtt.enums import CallbackAPIVersion

from bench.agents.protocol import percentiles, serve_in_thread, setup_logging
from gateway.codecs.sparkplug.sparkplug_b_pb2 import Payload

REBIRTH = "Node Control/Rebirth"


class Host:
    def __init__(self, group: str, edge_node: str, devices: int) -> None:
        self.group = group
        self.edge_node = edge_node
        self.devices = devices
        self.count = 0  # DDATA metrics
        self.messages = 0
        self.historical = 0
        self.latencies: list[float] = []  # since the last snap
        self.window: list[float] = []  # since the last mark
        self.last: dict[str, float] = {}  # metric name → last value
        self.names: dict[int, str] = {}
        self.sessions = 0  # NBIRTHs with a new bdSeq
        self.births = 0  # NBIRTHs
        self.dbirths = 0
        self.seq_gaps = 0
        self.bdseq: int | None = None
        self._seq: int | None = None
        self._asked = False
        self._lock = threading.Lock()
        self._born = threading.Condition(self._lock)
        self.client: paho.Client | None = None

    def on_message(self, client: paho.Client, userdata: Any, msg: paho.MQTTMessage) -> None:
        now = time.time()
        kind = msg.topic.split("/")[2]
        if kind in ("NCMD", "DCMD", "STATE"):
            return
        payload = Payload.FromString(msg.payload)
        with self._lock:
            self.messages += 1
            if kind == "NDEATH":
                return
            if kind == "NBIRTH":
                bdseq = next((int(m.long_value) for m in payload.metrics if m.name == "bdSeq"), None)
                if bdseq != self.bdseq:
                    self.sessions += 1
                    self.bdseq = bdseq
                self.births += 1
                self.dbirths = 0
                self._seq = payload.seq
                self._born.notify_all()
                return
            if self._seq is not None and payload.seq != (self._seq + 1) % 256:
                self.seq_gaps += 1
            self._seq = payload.seq
            if kind == "DBIRTH":
                for m in payload.metrics:
                    self.names[m.alias] = m.name
                self.dbirths += 1
                self._born.notify_all()
                return
            if kind != "DDATA":
                return
            if not self.names and not self._asked:  # born before we listened: ask, as a host does
                self._asked = True
                self._publish_rebirth()
            for m in payload.metrics:
                self.count += 1
                if m.is_historical:
                    self.historical += 1
                    continue
                latency = (now - m.timestamp / 1000.0) * 1000.0
                self.latencies.append(latency)
                self.window.append(latency)
                if m.WhichOneof("value") == "double_value":
                    self.last[self.names.get(m.alias, "")] = m.double_value

    # --- commands ------------------------------------------------------------------------------

    def mark(self, request: dict[str, Any]) -> dict[str, Any]:
        with self._lock:
            self.window = []
        return self.snap(request)

    def snap(self, request: dict[str, Any]) -> dict[str, Any]:
        with self._lock:
            latencies, self.latencies = self.latencies, []
            window = list(self.window)
            return {
                "count": self.count,
                "messages": self.messages,
                "historical": self.historical,
                "latency": percentiles(latencies),
                "window": percentiles(window),
                "sessions": self.sessions,
                "births": self.births,
                "dbirths": self.dbirths,
                "seq_gaps": self.seq_gaps,
                "bdseq": self.bdseq,
            }

    def values(self, request: dict[str, Any]) -> dict[str, Any]:
        with self._lock:
            return {"last": dict(self.last)}

    def _publish_rebirth(self) -> None:
        assert self.client is not None
        ncmd = Payload()
        ncmd.timestamp = int(time.time() * 1000)
        metric = ncmd.metrics.add()
        metric.name = REBIRTH
        metric.datatype = 11  # Boolean
        metric.boolean_value = True
        self.client.publish(f"spBv1.0/{self.group}/NCMD/{self.edge_node}", ncmd.SerializeToString(), 0)

    def rebirth(self, request: dict[str, Any]) -> dict[str, Any]:
        """NCMD rebirth; seconds until the NBIRTH and `devices` DBIRTHs after it have arrived."""
        with self._lock:
            births = self.births
            started = time.perf_counter()
            self._publish_rebirth()
            first = self._born.wait_for(lambda: self.births > births, timeout=30)
            done = first and self._born.wait_for(lambda: self.dbirths >= self.devices, timeout=30)
            elapsed = time.perf_counter() - started
        return {"seconds": elapsed if done else None, "dbirths": self.dbirths}


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("--port", type=int, required=True)
    parser.add_argument("--group", default="cnc")
    parser.add_argument("--edge-node", default="cnc-gateway")
    parser.add_argument("--devices", type=int, default=1)
    args = parser.parse_args()
    setup_logging()
    host = Host(args.group, args.edge_node, args.devices)
    client = paho.Client(CallbackAPIVersion.VERSION2, client_id=f"bench-spb-{uuid.uuid4().hex[:8]}")
    host.client = client
    subscribed: list[bool] = []
    client.on_message = host.on_message
    client.on_connect = lambda c, u, f, r, p: c.subscribe(f"spBv1.0/{args.group}/#", 0)
    client.on_subscribe = lambda *a: subscribed.append(True)
    client.reconnect_delay_set(0.05, 0.5)
    client.connect("127.0.0.1", args.port, keepalive=60)
    while not subscribed:
        client.loop(timeout=0.05)
    handlers = {"snap": host.snap, "mark": host.mark, "values": host.values, "rebirth": host.rebirth}
    serve_in_thread(handlers, client.disconnect)
    client.loop_forever(retry_first_connection=True)


if __name__ == "__main__":
    main()
