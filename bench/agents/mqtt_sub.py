"""An MQTT subscriber (paho, its own process) that counts changes and measures their latency.

Payloads are the gateway's JSON (`{"value":…,"ts":"…Z","quality":"good"…}`), or the
raw baseline's imitation of it. The latency of a message is its receipt time minus
its `ts` (the controller's source timestamp, millisecond resolution). The value is
the noise sequence number, so the last value per topic tells which change a topic
ended at.

With `--check`, every message also goes through bench/delivery.py (order per topic, retransmissions,
duplicates; `check` compares with what the in-process source wrote), and `--persistent` keeps a
session the broker holds across its restarts (clean session off, a fixed client id, the
subscription made only when the broker did not keep it), as a historian subscribes at QoS 1.

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
from bench.delivery import DeliveryCheck

TS_KEY = b'"ts":'
VALUE_KEY = b'"value":'
GOOD = (b'"quality":"good"', b'"quality": "good"')


class Counter:
    def __init__(self, expect: int, check: bool = False) -> None:
        self.check = DeliveryCheck() if check else None
        self._check_lock = threading.Lock()
        self.connects = 0
        self.resumed = 0  # connections that found the broker still holding our session
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
        check = self.check
        if check is not None:
            with self._check_lock:
                check.feed(topic, payload, msg.dup)
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
            "connects": self.connects,
            "resumed": self.resumed,
            **self._check_counts(),
        }

    def _check_counts(self) -> dict[str, Any]:
        check = self.check
        if check is None:
            return {}
        return {
            "distinct": check.distinct,
            "redelivered": check.redelivered,
            "redelivered_dup": check.redelivered_dup,
        }

    def verdict(self, request: dict[str, Any]) -> dict[str, Any]:
        """`{"cmd": "check", "topics": [...], "written": n}`: bench/delivery.py's verdict."""
        if self.check is None:
            raise RuntimeError("check needs --check")
        with self._check_lock:
            return self.check.verdict(request["topics"], int(request["written"])).as_dict()

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
    parser.add_argument("--check", action="store_true", help="check order and duplicates (bench/delivery.py)")
    parser.add_argument("--persistent", action="store_true", help="a session the broker keeps (QoS 1)")
    parser.add_argument("--client-id", default=None)
    args = parser.parse_args()
    setup_logging()
    counter = Counter(args.expect, check=args.check)
    client = paho.Client(
        CallbackAPIVersion.VERSION2,
        client_id=args.client_id or f"bench-sub-{uuid.uuid4().hex[:8]}",
        clean_session=not args.persistent,
    )
    client.reconnect_delay_set(0.05, 0.5)
    subscribed: list[bool] = []
    client.on_message = counter.on_message

    def on_connect(c: paho.Client, userdata: Any, flags: Any, reason: Any, props: Any) -> None:
        if reason.is_failure:
            return
        counter.connects += 1
        if args.persistent and flags.session_present:
            counter.resumed += 1  # the broker kept our subscription and queued messages: rely on it
            return
        c.subscribe([(t, args.qos) for t in args.topic])

    client.on_connect = on_connect
    client.on_subscribe = lambda *a: subscribed.append(True)
    client.connect("127.0.0.1", args.port, keepalive=60)
    while not subscribed:
        client.loop(timeout=0.05)
    threading.Thread(target=sample_backlog, args=(client, counter), name="backlog", daemon=True).start()
    handlers = {
        "snap": counter.snap,
        "mark": counter.mark,
        "values": counter.values,
        "check": counter.verdict,
    }
    serve_in_thread(handlers, client.disconnect)
    client.loop_forever()


if __name__ == "__main__":
    main()
