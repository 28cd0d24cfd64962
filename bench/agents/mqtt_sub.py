"""An MQTT subscriber (paho, its own process) that counts changes and measures their latency.

Payloads are the gateway's JSON (`{"value":…,"ts":"…Z","quality":"good"…}`), or the
raw baseline's imitation of it. The latency of a message is its receipt time minus
its `ts` (the controller's source timestamp, millisecond resolution). The value is
the noise sequence number, so the last value per topic tells which change a topic
ended at.

A Python subscriber has a ceiling of its own (the baselines' paho → Mosquitto →
paho figure). When messages arrive faster than it reads them, they wait in its
socket, and their latency grows there, after the gateway. So a thread samples the
bytes waiting unread in the socket (FIONREAD) every 20 ms: `backlog` in a mark's
window, with the mean size of a message to turn it into messages.
"""

from __future__ import annotations

import argparse
import fcntl
import struct
import termios
import threading
import time
import uuid
from datetime import datetime
from typing import Any

import paho.mqtt.client as paho
from paho.mqtt.enums import CallbackAPIVersion

from bench.agents.protocol import percentiles, serve_in_thread, setup_logging

TS_KEY = b'"ts":'
VALUE_KEY = b'"value":'
GOOD = (b'"quality":"good"', b'"quality": "good"')


class Counter:
    def __init__(self, expect: int) -> None:
        self.count = 0
        self.retained = 0
        self.latencies: list[float] = []  # since the last snap
        self.window: list[float] = []  # since the last mark
        self.last: dict[str, float] = {}
        self.good: set[str] = set()
        self.expect = expect
        self.all_good_at: float | None = None
        self.first_at: float | None = None
        self.last_at: float | None = None
        self._seconds: dict[bytes, float] = {}
        self.bytes = 0  # topics and payloads received
        self.backlog: list[float] = []  # bytes unread in the socket, sampled since the last mark

    def epoch(self, ts: bytes) -> float:
        """`2026-05-06T07:08:09.123Z` as seconds since the epoch (the seconds part is cached)."""
        head = ts[:19]
        base = self._seconds.get(head)
        if base is None:
            base = datetime.fromisoformat(head.decode() + "+00:00").timestamp()
            if len(self._seconds) > 100_000:
                self._seconds.clear()
            self._seconds[head] = base
        return base + int(ts[20:23]) / 1000.0

    def on_message(self, client: paho.Client, userdata: Any, msg: paho.MQTTMessage) -> None:
        now = time.time()
        payload = msg.payload
        topic = msg.topic
        self.bytes += len(payload) + len(topic)
        if msg.retain:
            self.retained += 1
        self.count += 1
        if self.first_at is None:
            self.first_at = now
        self.last_at = now
        t = payload.find(TS_KEY)
        if t < 0:
            return
        start = payload.find(b'"', t + len(TS_KEY)) + 1
        if not msg.retain:
            latency = (now - self.epoch(payload[start : start + 24])) * 1000.0
            self.latencies.append(latency)
            self.window.append(latency)
        v = payload.find(VALUE_KEY)
        if v >= 0:
            end = payload.find(b",", v)
            try:  # noqa: SIM105 - once per message: a try costs nothing, suppress() is a call
                self.last[topic] = float(payload[v + len(VALUE_KEY) : end])
            except ValueError:
                pass
        if GOOD[0] in payload or GOOD[1] in payload:
            if topic not in self.good:
                self.good.add(topic)
                if self.all_good_at is None and self.expect and len(self.good) >= self.expect:
                    self.all_good_at = now
        else:
            self.good.discard(topic)

    def mark(self, request: dict[str, Any]) -> dict[str, Any]:
        """Start a measurement window: `snap` then also reports the window's latencies so far."""
        self.window = []
        self.backlog = []
        return self.snap(request)

    def snap(self, request: dict[str, Any]) -> dict[str, Any]:
        latencies, self.latencies = self.latencies, []
        return {
            "count": self.count,
            "retained": self.retained,
            "latency": percentiles(latencies),
            "window": percentiles(self.window),
            "good": len(self.good),
            "all_good_at": self.all_good_at,
            "first_at": self.first_at,
            "last_at": self.last_at,
            "bytes": self.bytes,
            "backlog": percentiles(self.backlog),
        }

    def values(self, request: dict[str, Any]) -> dict[str, Any]:
        return {"last": dict(self.last)}


def sample_backlog(client: paho.Client, counter: Counter, every: float = 0.02) -> None:
    """Bytes the kernel holds for this subscriber that it has not read yet, every `every` s."""
    buf = bytearray(4)
    while True:
        time.sleep(every)
        sock = client.socket()
        if sock is None:
            continue
        try:
            fcntl.ioctl(sock.fileno(), termios.FIONREAD, buf)
        except (OSError, ValueError):
            continue
        counter.backlog.append(float(struct.unpack("i", buf)[0]))


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("--port", type=int, required=True)
    parser.add_argument("--topic", action="append", required=True)
    parser.add_argument("--qos", type=int, default=0)
    parser.add_argument("--expect", type=int, default=0, help="topics whose quality must all be good")
    args = parser.parse_args()
    setup_logging()
    counter = Counter(args.expect)
    client = paho.Client(CallbackAPIVersion.VERSION2, client_id=f"bench-sub-{uuid.uuid4().hex[:8]}")
    subscribed: list[bool] = []
    client.on_message = counter.on_message
    client.on_connect = lambda c, u, f, r, p: c.subscribe([(t, args.qos) for t in args.topic])
    client.on_subscribe = lambda *a: subscribed.append(True)
    client.connect("127.0.0.1", args.port, keepalive=60)
    while not subscribed:
        client.loop(timeout=0.05)
    threading.Thread(target=sample_backlog, args=(client, counter), name="backlog", daemon=True).start()
    serve_in_thread({"snap": counter.snap, "mark": counter.mark, "values": counter.values}, client.disconnect)
    client.loop_forever()


if __name__ == "__main__":
    main()
