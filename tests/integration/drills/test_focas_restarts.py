"""Drill: the controller-restart drill once more with a FOCAS machine (issue 25).

As tests/integration/drills/test_controller_restarts.py, but the gateway reads the simulator over
FOCAS2 (mappings/fanuc-sim.yaml, the simulator's FOCAS face on a free port): N times (3; 30 in soak)
kill the simulator (SIGKILL); within 2 s the values must be Bad on OPC UA and MQTT; start it again on
the same ports; within 5 s of it listening they must be Good again on both. The gateway's memory floor
must not rise across the cycles.
"""

from __future__ import annotations

import asyncio
import contextlib
import time
import uuid
from pathlib import Path
from typing import Any

import pytest
import yaml

from tests.integration.drills import processes
from tests.integration.drills.conftest import Report, count
from tests.integration.drills.memory import MIB, floor_growth, mib
from tests.integration.drills.test_controller_restarts import (
    BAD_WITHIN,
    GOOD_WITHIN,
    MEMORY_TOLERANCE,
    WARMUP,
    Quality,
    mqtt_quality,
    settled_rss,
)
from tests.integration.mqtt.conftest import Mosquitto, Recorder, subscriber
from tests.opcua_client import Client
from tests.waiting import free_port, wait_until

RESTARTS = count("controller_restarts")
MACHINE = "fanuc-sim"
WATCHED = ("Axes/X/Position", "Program/Block", "Feed/Override", "Machine/Run")


def fanuc_sim(port: int) -> dict[str, Any]:
    data = yaml.safe_load((processes.ROOT / "mappings" / "fanuc-sim.yaml").read_text())
    data["driver"].update(host="127.0.0.1", port=port, timeout=1.0, reconnect={"initial": 0.2, "max": 2.0})
    data.pop("jobs", None)
    return data


@pytest.mark.timeout(90 + 15 * RESTARTS)
async def test_focas_controller_restarts_turn_values_bad_then_good_without_growing_memory(
    mosquitto: Mosquitto, recorders: list[Recorder], tmp_path: Path, drill_report: Report
) -> None:
    sim_port, sim_ftp, focas_port, gw_port = free_port(), free_port(), free_port(), free_port()
    processes.write_yaml(tmp_path / "fanuc-sim.yaml", fanuc_sim(focas_port))
    mqtt = {"port": mosquitto.port, "client_id": f"drill-{uuid.uuid4().hex[:8]}", "keepalive": 5,
            "reconnect": {"initial": 0.1, "max": 1}}  # fmt: skip
    gw_file = processes.gateway_file(tmp_path, ["fanuc-sim.yaml"], opcua_port=gw_port, inbox_port=free_port(),
                                     mqtt=mqtt)  # fmt: skip
    sim = processes.simulator(tmp_path, sim_port, sim_ftp, "--loop", "demo.nc", "--speed", "20",
                              "--focas-port", str(focas_port))  # fmt: skip
    gateway = processes.gateway(tmp_path, gw_file)
    topics = [f"cnc/{MACHINE}/{path.lower()}" for path in WATCHED]
    rec = subscriber(recorders, mosquitto.port, topics=topics)
    quality = Quality()
    client = Client(f"opc.tcp://127.0.0.1:{gw_port}/cnc-gateway", timeout=5)
    rss: list[int] = []
    to_bad: list[float] = []
    to_good: list[float] = []
    try:
        await asyncio.to_thread(sim.start)
        await asyncio.to_thread(processes.wait_for_port, sim, focas_port)
        await asyncio.to_thread(gateway.start)
        await asyncio.to_thread(processes.wait_for_port, gateway, gw_port)
        await client.connect()
        nodes = [client.get_node(f"ns=2;s={MACHINE}/{path}") for path in WATCHED]
        subscription = await client.create_subscription(100, quality)
        await subscription.subscribe_data_change(nodes, queuesize=1)
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
            await asyncio.to_thread(processes.wait_for_port, sim, focas_port)
            back = time.monotonic()
            await wait_until(lambda: quality.all(False, nodes), timeout=GOOD_WITHIN, message="Good on OPC UA")
            await wait_until(lambda: mqtt_quality(rec, topics, "good"), timeout=GOOD_WITHIN,
                             message="Good on MQTT")  # fmt: skip
            to_good.append(time.monotonic() - back)
            assert gateway.alive, gateway.tail()
            rss.append(await settled_rss(gateway))
    finally:
        with contextlib.suppress(Exception):
            await client.disconnect()
        exit_code = await asyncio.to_thread(gateway.stop)
        await asyncio.to_thread(sim.stop)

    growth = floor_growth(rss, warmup=min(WARMUP, max(0, len(rss) - 2)))
    drill_report(
        "controller restarts (FOCAS)", restarts=RESTARTS, bad_after_max=f"{max(to_bad):.2f}s",
        good_after_max=f"{max(to_good):.2f}s", opcua_notifications=quality.notifications,
        mqtt_messages=len(rec.messages), rss=mib(rss), rss_floor_growth=f"{growth / MIB:.1f}MiB",
    )  # fmt: skip
    assert exit_code == 0, gateway.tail()
    assert "Traceback" not in gateway.log.read_text(errors="replace"), gateway.tail()
    assert growth <= MEMORY_TOLERANCE, f"gateway memory grew by {growth / MIB:.1f} MiB: {mib(rss)}"
