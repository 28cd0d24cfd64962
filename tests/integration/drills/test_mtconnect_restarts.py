"""Drill: an MTConnect adapter, or an upstream MTConnect agent, killed (SIGKILL) and restarted, many times.

`adapter`: the simulator (a process) serves SHDR; the gateway (a process) reads it with
mappings/laser-sim-shdr.yaml. `agent`: gateway A (a process) mirrors the simulator and
serves it as an MTConnect agent; gateway B (a process) follows A's stream with the
mapping `discover` writes. N times (3; 30 in soak) the upstream process is killed:
within 2 s the downstream values must turn Bad on OPC UA (an asyncua subscription) and
on MQTT; started again, within 5 s of it listening they must be Good again on both.

A killed agent loses the end of its buffer file, so it comes back with a new instanceId
(store.py); the follower must notice every one of those restarts and say so, and must
never report the stream going on with a gap it did not report: its log is read for the
restarts it saw and for gaps.
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
from asyncua import Node, ua

from tests.integration.drills import processes
from tests.integration.drills.conftest import Report, count
from tests.integration.mqtt.conftest import Mosquitto, Recorder, subscriber
from tests.opcua_client import Client
from tests.waiting import free_port, wait_until

RESTARTS = count("mtconnect_restarts")
BAD_WITHIN = 2.0
GOOD_WITHIN = 5.0
ROOT = processes.ROOT


class Quality:
    def __init__(self) -> None:
        self.latest: dict[ua.NodeId, ua.StatusCode] = {}

    def datachange_notification(self, node: Node, val: Any, data: Any) -> None:
        self.latest[node.nodeid] = data.monitored_item.Value.StatusCode or ua.StatusCode()

    def all(self, bad: bool, nodes: list[Node]) -> bool:
        codes = [self.latest.get(n.nodeid) for n in nodes]
        return all(c is not None and (c.is_bad() if bad else c.is_good()) for c in codes)


def mqtt_quality(rec: Recorder, topics: list[str], quality: str) -> bool:
    return all((rec.last_json(t) or {}).get("quality") == quality for t in topics)


def shdr_mapping(port: int) -> dict[str, Any]:
    data = yaml.safe_load((ROOT / "mappings" / "laser-sim-shdr.yaml").read_text())
    data["driver"].update(host="127.0.0.1", port=port, reconnect={"initial": 0.1, "max": 1.0, "factor": 2})
    return data


def relay_mapping(agent_port: int) -> dict[str, Any]:
    """What discover writes from A's probe, for the watched paths (kept short: the drill needs four)."""
    return {
        "machine": "relay",
        "driver": {"type": "mtconnect", "url": f"http://127.0.0.1:{agent_port}", "device": "laser-sim",
                   "interval": 50, "heartbeat": 500, "reconnect": {"initial": 0.1, "max": 1.0, "factor": 2}},
        "variables": [
            {"path": "Axes/X/Position", "source": "Xact", "type": "Double", "unit": "mm"},
            {"path": "Program/Line", "source": "line", "type": "Int64"},
            {"path": "Feed/Override", "source": "feed_ovr", "type": "Double"},
            {"path": "Machine/Execution", "source": "execution", "type": "String"},
        ],
    }  # fmt: skip


WATCHED = {
    "adapter": ("laser-shdr", ("Axes/X/Position", "Program/Block", "Feed/Override", "Machine/Execution")),
    "agent": ("relay", ("Axes/X/Position", "Program/Line", "Feed/Override", "Machine/Execution")),
}


@pytest.mark.parametrize("mode", ["adapter", "agent"])
@pytest.mark.timeout(120 + 25 * RESTARTS)
async def test_upstream_kills_turn_values_bad_then_good(
    mode: str, mosquitto: Mosquitto, recorders: list[Recorder], tmp_path: Path, drill_report: Report
) -> None:
    machine, watched = WATCHED[mode]
    sim_port, sim_ftp, gw_port, up_port = free_port(), free_port(), free_port(), free_port()
    mqtt = {"port": mosquitto.port, "client_id": f"drill-{uuid.uuid4().hex[:8]}", "keepalive": 5,
            "reconnect": {"initial": 0.1, "max": 1}}  # fmt: skip
    started: list[processes.Process] = []
    if mode == "adapter":
        args = ("--shdr-port", str(up_port), "--loop", "demo.nc", "--speed", "20")
        upstream = processes.simulator(tmp_path, sim_port, sim_ftp, *args)
        processes.write_yaml(tmp_path / "machine.yaml", shdr_mapping(up_port))
    else:
        sim = processes.simulator(tmp_path, sim_port, sim_ftp, "--loop", "demo.nc", "--speed", "20")
        started.append(sim)
        a_dir = tmp_path / "a"
        a_dir.mkdir()
        processes.write_yaml(a_dir / "laser-sim.yaml", processes.laser_sim(sim_port))
        a_file = processes.gateway_file(
            a_dir, ["laser-sim.yaml"], opcua_port=free_port(), inbox_port=free_port()
        )
        data = yaml.safe_load(a_file.read_text())
        data["mtconnect"] = {"host": "127.0.0.1", "port": up_port, "persist": True}
        processes.write_yaml(a_file, data)
        upstream = processes.gateway(a_dir, a_file)
        processes.write_yaml(tmp_path / "machine.yaml", relay_mapping(up_port))
    gw_file = processes.gateway_file(
        tmp_path, ["machine.yaml"], opcua_port=gw_port, inbox_port=free_port(), mqtt=mqtt
    )
    gateway = processes.gateway(tmp_path, gw_file)
    topics = [f"cnc/{machine}/{path.lower()}" for path in watched]
    rec = subscriber(recorders, mosquitto.port, topics=topics)
    quality = Quality()
    client = Client(f"opc.tcp://127.0.0.1:{gw_port}/cnc-gateway", timeout=5)
    to_bad: list[float] = []
    to_good: list[float] = []
    try:
        for process in started:
            await asyncio.to_thread(process.start)
            await asyncio.to_thread(processes.wait_for_port, process, sim_port)
        await asyncio.to_thread(upstream.start)
        await asyncio.to_thread(processes.wait_for_port, upstream, up_port)
        await asyncio.to_thread(gateway.start)
        await asyncio.to_thread(processes.wait_for_port, gateway, gw_port)
        await client.connect()
        nodes = [client.get_node(f"ns=2;s={machine}/{path}") for path in watched]
        subscription = await client.create_subscription(100, quality)
        await subscription.subscribe_data_change(nodes, queuesize=1)
        await wait_until(lambda: quality.all(False, nodes), timeout=30, message="Good on OPC UA at start")
        await wait_until(
            lambda: mqtt_quality(rec, topics, "good"), timeout=30, message="Good on MQTT at start"
        )
        for cycle in range(RESTARTS):
            killed = time.monotonic()
            await asyncio.to_thread(upstream.kill)
            await wait_until(lambda: quality.all(True, nodes), timeout=BAD_WITHIN,
                             message=f"Bad on OPC UA within {BAD_WITHIN} s of kill {cycle + 1}")  # fmt: skip
            await wait_until(lambda: mqtt_quality(rec, topics, "bad"),
                             timeout=max(0.0, BAD_WITHIN - (time.monotonic() - killed)),
                             message=f"Bad on MQTT within {BAD_WITHIN} s of kill {cycle + 1}")  # fmt: skip
            to_bad.append(time.monotonic() - killed)
            await asyncio.to_thread(upstream.start)
            await asyncio.to_thread(processes.wait_for_port, upstream, up_port)
            back = time.monotonic()
            await wait_until(lambda: quality.all(False, nodes), timeout=GOOD_WITHIN,
                             message=f"Good on OPC UA {GOOD_WITHIN} s after restart {cycle + 1}")  # fmt: skip
            await wait_until(lambda: mqtt_quality(rec, topics, "good"),
                             timeout=max(0.0, GOOD_WITHIN - (time.monotonic() - back)),
                             message=f"Good on MQTT {GOOD_WITHIN} s after restart {cycle + 1}")  # fmt: skip
            to_good.append(time.monotonic() - back)
            assert gateway.alive, gateway.tail()
    finally:
        with contextlib.suppress(Exception):
            await client.disconnect()
        exit_code = await asyncio.to_thread(gateway.stop)
        await asyncio.to_thread(upstream.stop)
        for process in started:
            await asyncio.to_thread(process.stop)

    log = gateway.log.read_text(errors="replace")
    restarts_seen = log.count("the agent restarted")
    gaps = log.count("a gap in the stream")
    drill_report(
        f"mtconnect {mode} restarts", restarts=RESTARTS, bad_after_max=f"{max(to_bad):.2f}s",
        good_after_max=f"{max(to_good):.2f}s", agent_restarts_seen=restarts_seen, gaps_reported=gaps,
        mqtt_messages=len(rec.messages),
    )  # fmt: skip
    assert exit_code == 0, gateway.tail()
    assert "Traceback" not in log, gateway.tail()
    if mode == "agent":
        # a kill loses the agent's unflushed buffer: it comes back with a new instanceId, seen as such
        assert restarts_seen == RESTARTS and gaps == 0, gateway.tail()
