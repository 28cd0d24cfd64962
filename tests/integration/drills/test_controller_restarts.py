"""Drill: the controller dies (SIGKILL) and comes back, again and again.

The simulator runs as a process of its own, so it can be killed like a PLC that
loses power (`opcua`: the laser read over OPC UA; `modbus`: its chiller, read
over Modbus TCP with mappings/chiller-sim.yaml); the gateway runs as a process of
its own, so its memory can be read from /proc. N times (3; 30 in soak): kill the
simulator; within 2 s the machine's values must turn Bad on OPC UA (a real asyncua
subscription to the gateway) and on MQTT; start the simulator again on the same
ports; within 5 s of it listening the values must be Good again on both.

Memory: the gateway's RSS is read after each cycle, once everything is Good. The
drill fails if the floor of those samples rises after a warm-up (see memory.py):
a leak per reconnect would raise it by the same amount every cycle. The
deadlines above need `reconnect.max` below about 4 s (here 2 s; the shipped
laser-sim.yaml uses 10 s, fewer attempts against a machine switched off for the night).
"""

from __future__ import annotations

import asyncio
import contextlib
import time
import uuid
from pathlib import Path
from typing import Any

import pytest
from asyncua import Node, ua

from tests.integration.drills import processes
from tests.integration.drills.conftest import Report, count
from tests.integration.drills.memory import MIB, floor_growth, mib
from tests.integration.mqtt.conftest import Mosquitto, Recorder, subscriber
from tests.opcua_client import Client
from tests.waiting import free_port, wait_until

RESTARTS = count("controller_restarts")
WATCHED = {
    "opcua": ("laser-sim", ("Axes/X/Position", "Program/Block", "Feed/Override", "Machine/State")),
    "modbus": ("chiller", ("Temperatures/Supply", "Flow", "Setpoint", "PumpOn", "Faults/Any")),
}
BAD_WITHIN = 2.0  # s after the kill: the drill's requirement
GOOD_WITHIN = 5.0  # s after the controller listens again
WARMUP = 2  # cycles before memory must be flat (caches, asyncua type tables, allocator arenas)
MEMORY_TOLERANCE = 8 * MIB


class Quality:
    """The latest StatusCode per watched node, from the test's own OPC UA subscription."""

    def __init__(self) -> None:
        self.latest: dict[ua.NodeId, ua.StatusCode] = {}
        self.notifications = 0

    def datachange_notification(self, node: Node, val: Any, data: Any) -> None:
        self.notifications += 1
        self.latest[node.nodeid] = data.monitored_item.Value.StatusCode or ua.StatusCode()

    def all(self, bad: bool, nodes: list[Node]) -> bool:
        codes = [self.latest.get(n.nodeid) for n in nodes]
        return all(c is not None and (c.is_bad() if bad else c.is_good()) for c in codes)


def mqtt_quality(rec: Recorder, topics: list[str], quality: str) -> bool:
    return all((rec.last_json(t) or {}).get("quality") == quality for t in topics)


@pytest.mark.parametrize("device", ["opcua", "modbus"])
@pytest.mark.timeout(90 + 15 * RESTARTS)
async def test_controller_restarts_turn_values_bad_then_good_without_growing_memory(
    device: str, mosquitto: Mosquitto, recorders: list[Recorder], tmp_path: Path, drill_report: Report
) -> None:
    machine, watched = WATCHED[device]
    sim_port, sim_ftp, gw_port, modbus_port = free_port(), free_port(), free_port(), free_port()
    processes.write_yaml(tmp_path / "laser-sim.yaml", processes.laser_sim(sim_port))
    processes.write_yaml(tmp_path / "chiller-sim.yaml", processes.chiller_sim(modbus_port))
    mqtt = {"port": mosquitto.port, "client_id": f"drill-{uuid.uuid4().hex[:8]}", "keepalive": 5,
            "reconnect": {"initial": 0.1, "max": 1}}  # fmt: skip
    mappings = ["laser-sim.yaml"] + (["chiller-sim.yaml"] if device == "modbus" else [])
    gw_file = processes.gateway_file(tmp_path, mappings, opcua_port=gw_port, inbox_port=free_port(),
                                     mqtt=mqtt)  # fmt: skip
    sim = processes.simulator(tmp_path, sim_port, sim_ftp, "--loop", "demo.nc", "--speed", "20",
                              "--modbus-port", str(modbus_port) if device == "modbus" else "off")  # fmt: skip
    gateway = processes.gateway(tmp_path, gw_file)
    topics = [f"cnc/{machine}/{path.lower()}" for path in watched]
    rec = subscriber(recorders, mosquitto.port, topics=topics)
    quality = Quality()
    client = Client(f"opc.tcp://127.0.0.1:{gw_port}/cnc-gateway", timeout=5)
    rss: list[int] = []
    to_bad: list[float] = []
    to_good: list[float] = []
    try:
        await asyncio.to_thread(sim.start)
        await asyncio.to_thread(processes.wait_for_port, sim, sim_port)
        await asyncio.to_thread(gateway.start)
        await asyncio.to_thread(processes.wait_for_port, gateway, gw_port)
        await client.connect()
        nodes = [client.get_node(f"ns=2;s={machine}/{path}") for path in watched]
        subscription = await client.create_subscription(100, quality)
        await subscription.subscribe_data_change(nodes, queuesize=1)

        async def all_good() -> None:
            await wait_until(lambda: quality.all(False, nodes), timeout=GOOD_WITHIN, message="Good on OPC UA")
            await wait_until(lambda: mqtt_quality(rec, topics, "good"), timeout=GOOD_WITHIN,
                             message="Good on MQTT")  # fmt: skip

        await wait_until(lambda: quality.all(False, nodes), timeout=30, message="Good on OPC UA at start")
        await wait_until(
            lambda: mqtt_quality(rec, topics, "good"), timeout=30, message="Good on MQTT at start"
        )
        rss.append(await settled_rss(gateway))
        for cycle in range(RESTARTS):
            killed = time.monotonic()
            await asyncio.to_thread(sim.kill)
            await wait_until(lambda: quality.all(True, nodes), timeout=BAD_WITHIN,
                             message=f"Bad on OPC UA within {BAD_WITHIN} s of kill {cycle + 1}")  # fmt: skip
            await wait_until(lambda: mqtt_quality(rec, topics, "bad"),
                             timeout=max(0.0, BAD_WITHIN - (time.monotonic() - killed)),
                             message=f"Bad on MQTT within {BAD_WITHIN} s of kill {cycle + 1}")  # fmt: skip
            to_bad.append(time.monotonic() - killed)
            await asyncio.to_thread(sim.start)
            await asyncio.to_thread(processes.wait_for_port, sim, sim_port)
            back = time.monotonic()
            await all_good()
            to_good.append(time.monotonic() - back)
            assert gateway.alive, gateway.tail()
            rss.append(await settled_rss(gateway))
    finally:
        with contextlib.suppress(Exception):  # the gateway may be the thing that failed
            await client.disconnect()
        exit_code = await asyncio.to_thread(gateway.stop)
        await asyncio.to_thread(sim.stop)

    warmup = min(WARMUP, max(0, len(rss) - 2))
    growth = floor_growth(rss, warmup=warmup)
    drill_report(
        f"controller restarts ({device})", restarts=RESTARTS, bad_after_max=f"{max(to_bad):.2f}s",
        good_after_max=f"{max(to_good):.2f}s", opcua_notifications=quality.notifications,
        mqtt_messages=len(rec.messages), rss=mib(rss), rss_floor_growth=f"{growth / MIB:.1f}MiB",
    )  # fmt: skip
    assert exit_code == 0, gateway.tail()
    assert "Traceback" not in gateway.log.read_text(errors="replace"), gateway.tail()
    assert growth <= MEMORY_TOLERANCE, f"gateway memory grew by {growth / MIB:.1f} MiB: {mib(rss)}"


async def settled_rss(process: processes.Process) -> int:
    """The lowest of a few readings a little apart: a transient allocation is not the steady state."""
    readings = []
    for _ in range(5):
        readings.append(process.rss())
        await asyncio.sleep(0.05)
    return min(readings)
