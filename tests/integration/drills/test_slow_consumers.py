"""Drill: three consumers stop reading while the machine streams; the gateway's memory stays bounded and
everyone else keeps up.

The simulator (a process) runs the laser program and its noise mode: 100 Double
variables whose values are a global sequence number, 1,000 changes/s in all, so
a reader can tell exactly which changes it missed. The gateway (a process, so its
RSS can be read from /proc) mirrors them to OPC UA, MQTT and a COPYDATA
tcp-server target that sends every change (mode single, no rate limit).

Then, for N changes (10,000; 150,000 in soak), three consumers stall:
an MQTT subscriber that stops reading, an OPC UA client that never sends Publish
requests, and a COPYDATA receiver that never reads (consumers.py). Meanwhile:
- a normal MQTT subscriber (QoS 1) receives every one of the N changes;
- a normal OPC UA subscriber and a normal COPYDATA receiver keep receiving, and
  reach the newest value; the OPC UA one at no less than half the rate it had
  before the stall;
- the gateway's RSS, sampled through the stall, levels off: its floor does not
  keep rising (memory.py), and it stays within a fixed bound of where it started.
"""

from __future__ import annotations

import asyncio
import contextlib
import socket
import time
import uuid
from pathlib import Path

import pytest
import yaml
from asyncua import ua

from tests.integration.drills import processes
from tests.integration.drills.conftest import Report, count
from tests.integration.drills.consumers import (
    CopydataReader,
    OpcUaCounter,
    SequenceSubscriber,
    StalledOpcUa,
    stalled_copydata,
    stalled_mqtt,
)
from tests.integration.drills.memory import MIB, floor_growth, mib
from tests.integration.mqtt.conftest import Mosquitto
from tests.opcua_client import Client
from tests.waiting import free_port, wait_until

noise = pytest.importorskip("simulator.noise", reason="needs the simulator's noise mode (simulator/noise.py)")

CHANGES = count("slow_consumers")
NOISE_VARIABLES = 100
RATE = 1000  # noise changes/s
BASELINE = 2000  # changes watched before the stall, for the OPC UA rate to compare with
WATCHED = 10  # noise variables the normal OPC UA subscriber watches
FLOOR_TOLERANCE = 4 * MIB
BOUND = 64 * MIB  # RSS above its level before the stall
# What the gateway's OPC UA server promises (RevisedQueueSize) to keep per monitored item for a client that
# does not collect its notifications: a stalled client costs at most this many per variable it watches.
MAX_QUEUE_PER_ITEM = 1000


def noise_machine(sim_port: int, copydata_port: int) -> dict[str, object]:
    """The simulator's noise mapping, plus a COPYDATA id per variable and a target sending every change."""
    spec = noise.NoiseSpec(NOISE_VARIABLES, RATE)
    data = yaml.safe_load(noise.noise_mapping(spec, f"opc.tcp://127.0.0.1:{sim_port}", machine="noise"))
    for index, variable in enumerate(data["variables"], start=1):
        variable["copydata"] = {"id": index}
    data["copydata"] = {"targets": [{
        "name": "nesting", "transport": "tcp-server", "bind": "127.0.0.1", "port": copydata_port,
        "mode": "single", "max_rate": None, "max_clients": 4,
    }]}  # fmt: skip
    return data


@pytest.mark.timeout(120 + 3 * CHANGES // RATE)
async def test_stalled_consumers_cost_bounded_memory_and_nobody_else_slows(
    mosquitto: Mosquitto, tmp_path: Path, drill_report: Report
) -> None:
    sim_port, gw_port, copydata_port = free_port(), free_port(), free_port()
    processes.write_yaml(tmp_path / "laser-sim.yaml", processes.laser_sim(sim_port))
    processes.write_yaml(tmp_path / "noise.yaml", noise_machine(sim_port, copydata_port))
    mqtt = {"port": mosquitto.port, "client_id": f"drill-{uuid.uuid4().hex[:8]}"}
    gw_file = processes.gateway_file(tmp_path, ["laser-sim.yaml", "noise.yaml"], opcua_port=gw_port,
                                     inbox_port=free_port(), mqtt=mqtt)  # fmt: skip
    sim = processes.simulator(
        tmp_path, sim_port, free_port(), "--loop", "demo.nc", "--speed", "20",
        "--noise-variables", str(NOISE_VARIABLES), "--noise-rate", str(RATE),
    )  # fmt: skip
    gateway = processes.gateway(tmp_path, gw_file)
    endpoint = f"opc.tcp://127.0.0.1:{gw_port}/cnc-gateway"
    mqtt_sub = SequenceSubscriber(mosquitto.port, "cnc/noise/#")
    opcua = Client(endpoint, timeout=10)
    counter = OpcUaCounter()
    copydata = CopydataReader(set(range(1, NOISE_VARIABLES + 1)))
    stalled_opcua = StalledOpcUa(endpoint)
    stalled: list[socket.socket] = []
    samples: list[int] = []
    try:
        await asyncio.to_thread(sim.start)
        await asyncio.to_thread(processes.wait_for_port, sim, sim_port)
        await asyncio.to_thread(gateway.start)
        await asyncio.to_thread(processes.wait_for_port, gateway, gw_port)
        await asyncio.to_thread(processes.wait_for_port, gateway, copydata_port)
        await asyncio.to_thread(mqtt_sub.start)
        await opcua.connect()
        noise_nodes = [
            opcua.get_node(f"ns=2;s=noise/{v['path']}")
            for v in noise_machine(sim_port, copydata_port)["variables"]
        ]  # type: ignore[index]
        subscription = await opcua.create_subscription(100, counter)
        await subscription.subscribe_data_change(noise_nodes[:WATCHED], queuesize=1)
        await copydata.connect(copydata_port)
        await wait_until(lambda: mqtt_sub.newest and counter.newest and copydata.newest, timeout=30,
                         message="noise on MQTT, OPC UA and COPYDATA")  # fmt: skip

        # Before the stall: the OPC UA subscriber's pace, and the gateway's memory.
        start, notified, began = mqtt_sub.newest, counter.notifications, time.monotonic()
        await wait_until(lambda: mqtt_sub.newest >= start + BASELINE, timeout=10 + 3 * BASELINE / RATE,
                         message="the baseline window")  # fmt: skip
        opcua_before = (counter.notifications - notified) / (time.monotonic() - began)
        before = min(await rss_readings(gateway, 5))

        # The stall.
        stalled.append(await asyncio.to_thread(stalled_mqtt, mosquitto.port, "cnc/#"))
        stalled.append(await asyncio.to_thread(stalled_copydata, copydata_port))
        all_nodes = [n.nodeid for n in noise_nodes] + laser_node_ids(opcua)
        await stalled_opcua.start(all_nodes)
        first, notified, began = mqtt_sub.newest + 1, counter.notifications, time.monotonic()
        last = first + CHANGES - 1
        sampler = asyncio.create_task(sample_rss(gateway, samples), name="drill:rss")
        try:
            await wait_until(lambda: mqtt_sub.newest >= last, timeout=30 + 3 * CHANGES / RATE, interval=0.2,
                             message=f"{CHANGES} changes to stream past the stalled consumers")  # fmt: skip
        finally:
            sampler.cancel()
            await asyncio.gather(sampler, return_exceptions=True)
        opcua_during = (counter.notifications - notified) / (time.monotonic() - began)
        # The normal consumers reach the newest values, and MQTT has every change of the window.
        await wait_until(
            lambda: counter.newest >= last, timeout=10, message="OPC UA to reach the newest values"
        )
        await wait_until(
            lambda: copydata.newest >= last, timeout=10, message="COPYDATA to reach the newest values"
        )
        await wait_until(
            lambda: mqtt_sub.missing(first, last) == 0, timeout=15, message="every change on MQTT"
        )
        assert gateway.alive, gateway.tail()
    finally:
        for sock in stalled:
            sock.close()
        await stalled_opcua.stop()
        await copydata.close()
        with contextlib.suppress(Exception):  # the gateway may be what failed
            await opcua.disconnect()
        await asyncio.to_thread(mqtt_sub.stop)
        exit_code = await asyncio.to_thread(gateway.stop)
        await asyncio.to_thread(sim.stop)

    growth = floor_growth(samples, warmup=len(samples) // 4)
    peak = max(samples)
    ratio = opcua_during / opcua_before if opcua_before else 0.0
    drill_report(
        "slow consumers", changes=CHANGES, mqtt_missing=mqtt_sub.missing(first, last),
        opcua_rate_before=f"{opcua_before:.0f}/s", opcua_rate_during=f"{opcua_during:.0f}/s",
        copydata_frames=copydata.frames, stalled_opcua_items=stalled_opcua.items,
        stalled_opcua_queue=stalled_opcua.revised_queue, rss_before=f"{before / MIB:.1f}MiB",
        rss_peak=f"{peak / MIB:.1f}MiB", rss_floor_growth=f"{growth / MIB:.1f}MiB", rss=mib(samples),
    )  # fmt: skip
    assert exit_code == 0, gateway.tail()
    assert 1 <= stalled_opcua.revised_queue <= MAX_QUEUE_PER_ITEM, stalled_opcua.revised_queue
    assert ratio >= 0.5, f"the OPC UA subscriber slowed from {opcua_before:.0f}/s to {opcua_during:.0f}/s"
    assert growth <= FLOOR_TOLERANCE, f"the gateway's memory keeps growing: {mib(samples)}"
    assert peak - before <= BOUND, (
        f"the gateway's memory grew by {(peak - before) / MIB:.0f} MiB: {mib(samples)}"
    )


def laser_node_ids(client: Client) -> list[ua.NodeId]:
    """Every variable of the laser-sim machine, as the stalled client would subscribe to them."""
    data = yaml.safe_load((processes.ROOT / "mappings" / "laser-sim.yaml").read_text())
    return [client.get_node(f"ns=2;s=laser-sim/{v['path']}").nodeid for v in data["variables"]]


async def rss_readings(process: processes.Process, n: int) -> list[int]:
    out = []
    for _ in range(n):
        out.append(process.rss())
        await asyncio.sleep(0.05)
    return out


async def sample_rss(process: processes.Process, into: list[int], every: float = 0.25) -> None:
    while True:
        into.append(process.rss())
        await asyncio.sleep(every)
