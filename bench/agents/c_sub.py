"""A counting QoS 1 subscriber that is not ours and not Python: Mosquitto's `mosquitto_sub`.

Issue 28's flat-out step was bound by the paho subscriber (10-16k/s while the gateway reached the
broker at 53-73k/s), for the gateway and for paho's baseline alike, so the ratio said nothing about
the publisher. `mosquitto_sub` (C, libmosquitto) reads and acknowledges; this agent reads its output
(`-F '%t %p'`, one message a line) in a thread and feeds every message to bench/delivery.py, with
the same `snap` and `check` answers as bench/agents/mqtt_sub.py `--check`. DUP is not in
mosquitto_sub's output, so `redelivered_dup` stays 0 (the restart drill keeps the paho subscriber).

Ready once a probe published on `<prefix>/_bench_ready` comes back: the subscription is in place
(the probe is not counted).
"""

from __future__ import annotations

import argparse
import shutil
import subprocess
import threading
import time
import uuid
from typing import IO, Any

import paho.mqtt.client as paho
import psutil
from paho.mqtt.enums import CallbackAPIVersion

from bench.agents.protocol import serve_in_thread, setup_logging
from bench.delivery import DeliveryCheck

PROBE = "_bench_ready"


class Reader:
    """mosquitto_sub's lines into the checker; counts for `snap`."""

    def __init__(self) -> None:
        self.check = DeliveryCheck()
        self.lock = threading.Lock()
        self.count = 0
        self.probed = threading.Event()

    def run(self, stream: IO[bytes]) -> None:
        check, lock = self.check, self.lock
        for line in stream:
            topic, _, payload = line.rstrip(b"\n").partition(b" ")
            name = topic.decode()
            if name.endswith(PROBE):
                self.probed.set()
                continue
            with lock:
                check.feed(name, payload)
                self.count += 1


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("--port", type=int, required=True)
    parser.add_argument("--topic", required=True, help="a filter ending in /#")
    parser.add_argument("--qos", type=int, default=1)
    args = parser.parse_args()
    setup_logging()
    binary = shutil.which("mosquitto_sub")
    if binary is None:
        raise SystemExit("mosquitto_sub is not installed (make system-deps installs mosquitto-clients)")
    proc = subprocess.Popen(
        [binary, "-h", "127.0.0.1", "-p", str(args.port), "-q", str(args.qos), "-t", args.topic,
         "-i", f"bench-csub-{uuid.uuid4().hex[:8]}", "-F", "%t %p"],
        stdout=subprocess.PIPE, bufsize=1 << 20,
    )  # fmt: skip
    assert proc.stdout is not None
    child = psutil.Process(proc.pid)
    reader = Reader()
    threading.Thread(target=reader.run, args=(proc.stdout,), name="reader", daemon=True).start()
    probe = paho.Client(CallbackAPIVersion.VERSION2, client_id=f"bench-probe-{uuid.uuid4().hex[:8]}")
    probe.connect("127.0.0.1", args.port, keepalive=60)
    probe.loop_start()
    topic = args.topic.removesuffix("#") + PROBE
    deadline = time.monotonic() + 30
    while not reader.probed.wait(0.1):
        if time.monotonic() > deadline or proc.poll() is not None:
            raise SystemExit("mosquitto_sub did not subscribe")
        probe.publish(topic, b"{}", qos=0)
    probe.loop_stop()
    probe.disconnect()

    def snap(request: dict[str, Any]) -> dict[str, Any]:
        cpu = child.cpu_times()
        with reader.lock:
            check = reader.check
            return {
                "count": reader.count,
                "distinct": check.distinct,
                "redelivered": check.redelivered,
                "redelivered_dup": 0,
                "out_of_order": check.out_of_order,
                "c_cpu": cpu.user + cpu.system,
            }

    def verdict(request: dict[str, Any]) -> dict[str, Any]:
        with reader.lock:
            return reader.check.verdict(request["topics"], int(request["written"])).as_dict()

    thread = serve_in_thread({"snap": snap, "mark": snap, "check": verdict}, proc.terminate)
    thread.join()
    proc.wait(timeout=10)


if __name__ == "__main__":
    main()
