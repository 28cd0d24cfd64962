"""A QoS 1 subscriber across a shard's death: it misses the dead window's changes and no other, and is told.

Issue 29's shard-kill clause: two `shard: lease` shards (a 2-s lease) over the simulator's noise
variables, split into two machines of ten, whose every change is a sequence number (simulator/noise.py:
change k goes to variable (k - 1) mod 20), published at QoS 1 to a subscriber with a persistent session. The
shard serving one machine is SIGKILLed; the other takes it over. Then, in the window the subscriber
watched:
- the survivor's own machine: no change missing;
- the dead shard's machine: the missing changes form one run in its sequence, the dead window (from the
  last change the dead shard published to the first the new holder did), nothing missing before or after;
- reported, not silent: the dead shard's status topic got its will (offline), the survivor's status
  document lists the machine once it serves it, and the machine's status topic says so from the survivor.
"""

from __future__ import annotations

import asyncio
import json
import os
import re
import signal
import threading
import time
import urllib.request
import uuid
from pathlib import Path
from typing import Any

import paho.mqtt.client as paho
from paho.mqtt.enums import CallbackAPIVersion

from simulator.noise import NoiseSpec, noise_mapping
from tests.fleet_rig import Fleet, write_fleet
from tests.integration.drills import processes
from tests.integration.mqtt.conftest import Mosquitto
from tests.waiting import free_port, wait_until

VARIABLES, RATE = 20, 100.0
MACHINES = {"noise-a": (0, 10), "noise-b": (10, 10)}


def owner(seq: int) -> str:
    """The machine whose variable change `seq` went to."""
    return "noise-a" if (seq - 1) % VARIABLES < 10 else "noise-b"


class Historian:
    """A QoS 1 subscriber with a persistent session: each noise change's sequence number, and every status."""

    def __init__(self, port: int) -> None:
        self.seqs: dict[int, float] = {}  # sequence number -> when it arrived (monotonic)
        self.statuses: list[tuple[str, dict[str, Any], float]] = []
        self._lock = threading.Lock()
        self._subscribed = threading.Event()
        self.client = paho.Client(
            CallbackAPIVersion.VERSION2, client_id=f"historian-{uuid.uuid4().hex[:8]}", clean_session=False
        )
        self.client.on_connect = lambda c, *_: c.subscribe([("cnc/+/noise/#", 1), ("cnc/+/status", 1),
                                                             ("cnc/status/#", 1)])  # fmt: skip
        self.client.on_subscribe = lambda *_: self._subscribed.set()
        self.client.on_message = self._on_message
        self.port = port

    def start(self) -> Historian:
        self.client.connect("127.0.0.1", self.port, keepalive=30)
        self.client.loop_start()
        if not self._subscribed.wait(10):
            raise RuntimeError("no SUBACK for the historian")
        return self

    def _on_message(self, client: Any, userdata: Any, msg: paho.MQTTMessage) -> None:
        now = time.monotonic()
        data = json.loads(msg.payload)
        with self._lock:
            if msg.topic.endswith("/status") or "/status/" in msg.topic:
                self.statuses.append((msg.topic, data, now))
            elif isinstance(data.get("value"), float) and data["value"].is_integer():
                self.seqs.setdefault(int(data["value"]), now)

    def newest(self, machine: str) -> int:
        with self._lock:
            return max((s for s in self.seqs if owner(s) == machine), default=-1)

    def stop(self) -> None:
        self.client.disconnect()
        self.client.loop_stop()


def serving(port: int) -> set[str]:
    try:
        with urllib.request.urlopen(f"http://127.0.0.1:{port}/metrics", timeout=2) as answer:
            text = answer.read().decode()
    except OSError:
        return set()
    return set(re.findall(r'cnc_gateway_machine_connected\{machine="([^"]+)"\} 1\.0', text))


async def test_a_persistent_qos1_subscriber_misses_only_the_dead_window_and_is_told(
    tmp_path: Path, postgres_url: str, mosquitto: Mosquitto
) -> None:
    sim_port, http, opcua, inbox = free_port(), free_port(), free_port(), free_port()
    spec = NoiseSpec(VARIABLES, RATE, per_folder=10)
    names = []
    for machine, (first, count) in MACHINES.items():
        text = noise_mapping(
            spec, f"opc.tcp://127.0.0.1:{sim_port}", machine=machine, first=first, count=count
        )
        (tmp_path / f"{machine}.yaml").write_text(text)
        names.append(f"{machine}.yaml")
    sim = processes.simulator(tmp_path, sim_port, free_port(), "--noise-variables", str(VARIABLES),
                              "--noise-rate", str(RATE), "--noise-per-folder", "10")  # fmt: skip
    fleet_file = write_fleet(
        tmp_path, names, {"HTTP_PORT": http, "OPCUA_PORT": opcua, "INBOX_PORT": inbox}, shard="lease",
        restart="{initial: 60, max: 60}",
        gateway=f"queue: {postgres_url}\nlease_time: 2\nmqtt: {{port: {mosquitto.port}, qos: 1}}\n",
    )  # fmt: skip
    historian = Historian(mosquitto.port).start()
    try:
        await asyncio.to_thread(sim.start)
        await asyncio.to_thread(processes.wait_for_port, sim, sim_port)
        async with Fleet(fleet_file) as fleet:
            await wait_until(lambda: len(serving(http)) == 1 and len(serving(http + 1)) == 1, timeout=60,
                             interval=0.1, message="one machine on each shard")  # fmt: skip
            (dead,) = serving(http + 1)
            (kept,) = serving(http)
            await asyncio.sleep(1.0)
            lo = {m: historian.newest(m) for m in MACHINES}
            assert min(lo.values()) >= 0, "no noise on MQTT before the kill"
            os.kill(fleet.starts(2)[-1], signal.SIGKILL)
            killed = time.monotonic()
            await wait_until(lambda: serving(http) == set(MACHINES), timeout=30, interval=0.05,
                             message="shard 1 serving both machines")  # fmt: skip
            taken = time.monotonic()
            after = historian.newest(dead)
            await wait_until(lambda: historian.newest(dead) > after + 5 * VARIABLES, timeout=30,
                             message="the dead shard's machine streaming from shard 1")  # fmt: skip
            hi = (
                min(historian.newest(m) for m in MACHINES) - 2 * VARIABLES
            )  # what may still be in flight: out
            fleet.proc.send_signal(signal.SIGTERM)
            assert await asyncio.wait_for(fleet.proc.wait(), 30) == 0
    finally:
        historian.stop()
        await asyncio.to_thread(sim.stop)
    seqs = dict(historian.seqs)
    window = {m: [s for s in range(lo[m], hi + 1) if owner(s) == m] for m in MACHINES}
    missing = {m: [s for s in window[m] if s not in seqs] for m in MACHINES}
    assert missing[kept] == [], f"{kept} (shard 1's all along) lost changes: {missing[kept][:10]}"
    gone = missing[dead]
    assert gone, "no dead window at all: the kill was not seen"
    first, last = window[dead].index(gone[0]), window[dead].index(gone[-1])
    assert window[dead][first : last + 1] == gone, f"{dead}: more than one run missing: {gone}"
    before, resumed = window[dead][first - 1], window[dead][last + 1]
    assert seqs[before] <= taken and seqs[resumed] >= killed, (before, resumed, seqs[before], seqs[resumed])
    # Told: the dead shard's will, the survivor listing the machine, the machine's status from the survivor.
    offline = [
        d for t, d, at in historian.statuses if t == "cnc/status/shard-2" and d.get("state") == "offline"
    ]
    assert offline, "no will from the dead shard"
    listed = [d for t, d, at in historian.statuses if t == "cnc/status/shard-1" and at >= killed]
    assert any(dead in d.get("machines", []) for d in listed), listed
    told = [d for t, d, at in historian.statuses if t == f"cnc/{dead}/status" and at >= killed]
    assert any(d.get("state") == "connected" for d in told), told
    print(f"dead window: {len(gone)} changes of {dead}; failover {taken - killed:.2f} s")
