"""MTConnect in, OPC UA / MQTT / MTConnect out: a gateway reading another gateway's agent.

Gateway A mirrors the simulator (OPC UA) and serves it as an MTConnect agent, its buffer
kept on disk. Gateway B's mapping is what `discover` writes from A's /probe; B follows
A's stream and serves the machine again over OPC UA, MQTT and its own agent. An alarm
on the simulator travels A's alarms -> A's SYSTEM condition -> B's condition variable ->
B's alarms. When A restarts cleanly, B's values go Bad, then B resumes A's stream where it
stopped (same instanceId, no gap) and its values are Good again.
"""

from __future__ import annotations

import asyncio
from collections.abc import AsyncIterator
from contextlib import asynccontextmanager
from pathlib import Path
from typing import Any

import aiohttp
import yaml

from gateway.app import Gateway
from gateway.config.gateway import GatewayConfig
from gateway.config.loader import Config
from gateway.config.mapping import MachineMapping
from gateway.sinks.mtconnect.config import AgentConfig
from gateway.sinks.mtconnect.sink import MTConnectSink
from gateway.sources.mtconnect.agent_source import MTConnectSource
from gateway.sources.mtconnect.discover import discover_agent
from simulator.alarms import soft_limit
from simulator.runner import Simulator
from tests.integration.laser_rig import laser_mapping
from tests.integration.mqtt.conftest import Mosquitto, Recorder, mqtt_config, subscriber
from tests.opcua_client import Client
from tests.waiting import free_port, wait_until


def config(state: Path, mapping: MachineMapping, *, opcua_port: int, agent_port: int = 0, mqtt: Any = None,
           persist: bool = False) -> Config:  # fmt: skip
    gateway = GatewayConfig.model_validate(
        {
            "opcua": {"endpoint": f"opc.tcp://127.0.0.1:{opcua_port}/cnc-gateway", "security": ["None"]},
            "state_dir": str(state),
            "inbox": {"enabled": False},
        }
    ).model_copy(
        update={"mtconnect": AgentConfig(host="127.0.0.1", port=agent_port, persist=persist), "mqtt": mqtt}
    )
    return Config(gateway, (mapping,), state.parent)


@asynccontextmanager
async def running(cfg: Config) -> AsyncIterator[Gateway]:
    async with Gateway(cfg) as gw:
        task = asyncio.create_task(gw.run(), name="gateway")
        try:
            yield gw
        finally:
            task.cancel()
            await asyncio.gather(task, return_exceptions=True)


async def test_a_gateway_follows_another_gateways_agent_and_serves_it_everywhere(
    tmp_path: Path, mosquitto: Mosquitto, recorders: list[Recorder]
) -> None:
    sim = Simulator(opcua_port=0, ftp_port=0, speed=20.0, loop_program="demo.nc", store=tmp_path / "store")
    async with sim:
        a_agent_port = free_port()
        a_config = config(tmp_path / "a", laser_mapping(sim.opcua_port), opcua_port=free_port(),
                          agent_port=a_agent_port, persist=True)  # fmt: skip
        a_url = f"http://127.0.0.1:{a_agent_port}"
        async with running(a_config) as a:
            await wait_until(
                lambda: a.tree.machines["laser-sim"].status.is_connected, timeout=15, message="A up"
            )
            text = await discover_agent(a_url, machine="relay")
        data = yaml.safe_load(text)
        data["driver"].update(interval=20, heartbeat=500, reconnect={"initial": 0.1, "max": 0.5, "factor": 2})
        b_mapping = MachineMapping.model_validate(data)
        assert b_mapping.alarms is not None and b_mapping.alarms.source.type == "conditions"
        paths = {
            v.mtconnect.name: v.path
            for v in b_mapping.variables
            if v.mtconnect is not None and v.mtconnect.name
        }
        b_opcua = free_port()
        b_config = config(tmp_path / "b", b_mapping, opcua_port=b_opcua, mqtt=mqtt_config(mosquitto.port))
        xact = paths["Xact"]
        rec = subscriber(recorders, mosquitto.port, topics=[f"cnc/relay/{xact.lower()}"])
        async with running(b_config) as b:
            relay = b.tree.machines["relay"]
            node = b.tree.find("relay", xact)
            source = b.sources[0]
            assert isinstance(source, MTConnectSource)
            async with running(a_config) as a:
                await wait_until(
                    lambda: relay.status.is_connected and node.sample.good, timeout=15, message="B up"
                )
                a_node = a.tree.find("laser-sim", "Axes/X/Position")
                await wait_until(lambda: node.sample.value == a_node.sample.value, message="the same X")
                assert b.tree.find("relay", paths["execution"]).sample.value in ("READY", "ACTIVE")
                # MQTT and OPC UA show it Good
                topic = f"cnc/relay/{xact.lower()}"
                await wait_until(lambda: (rec.last_json(topic) or {}).get("quality") == "good", message="MQ")
                client = Client(f"opc.tcp://127.0.0.1:{b_opcua}/cnc-gateway", timeout=5)
                async with client:
                    dv = await client.get_node(f"ns=2;s=relay/{xact}").read_data_value()
                    assert dv.StatusCode is None or dv.StatusCode.is_good()
                # and B's own agent serves it again
                b_sink = b.sink("mtconnect", MTConnectSink)
                async with (
                    aiohttp.ClientSession() as session,
                    session.get(b_sink.url + "/current?path=//Linear") as r,
                ):
                    assert r.status == 200 and 'name="Xact"' in await r.text()
                # an alarm: simulator -> A's alarms -> A's SYSTEM condition -> B's condition -> B's alarms
                sim.machine.raise_alarm(soft_limit("X", "+", 7))
                assert b.alarms is not None
                manager = b.alarms.managers["relay"]
                await wait_until(lambda: any(r.active and r.id == "1001" for r in manager.records.values()),
                                 timeout=10, message="the alarm at B")  # fmt: skip
                sim.machine.reset()
                await wait_until(
                    lambda: not any(r.active for r in manager.records.values()), message="cleared at B"
                )
                instance, resumed = source.instance_id, source.resumed
            # A stops cleanly (its buffer on disk): B's values go Bad...
            await wait_until(
                lambda: node.sample.status == "BadNotConnected", timeout=5, message="Bad when A stops"
            )
            async with running(a_config):
                # ...and B resumes A's stream where it stopped: same numbering, no gap
                await wait_until(
                    lambda: source.resumed > resumed and node.sample.good, timeout=15, message="resumed"
                )
                assert source.instance_id == instance and source.gaps == 0 and source.restarts == 0
