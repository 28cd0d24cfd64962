"""The shipped laser-sim mapping run by a real Gateway against a real simulator, for alarm and command tests.

Everything on free loopback ports: the simulator (OPC UA and FTP, `speed` times
real time), the gateway's OPC UA server, and optionally a Mosquitto broker that
the gateway publishes to. The mapping's jobs and COPYDATA sections are left out:
these tests do not need them, and they would only slow the start.
"""

from __future__ import annotations

import asyncio
import contextlib
from collections.abc import AsyncIterator
from contextlib import asynccontextmanager
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from asyncua import ua

from gateway.app import Gateway
from gateway.config.gateway import GatewayConfig
from gateway.config.loader import Config, load_mapping
from gateway.config.mapping import MachineMapping
from gateway.sinks.mqtt.config import MachineMqtt, MqttConfig
from simulator.runner import Simulator
from tests.opcua_client import Client
from tests.waiting import free_port, wait_until

ROOT = Path(__file__).resolve().parents[2]
MACHINE = "laser-sim"
SPEED = 20.0


def laser_mapping(
    sim_port: int, *, mqtt_commands: bool = True, timeouts: dict[str, float] | None = None
) -> MachineMapping:
    mapping = load_mapping(
        ROOT / "mappings" / "laser-sim.yaml",
        environ={"LASER_SIM_ENDPOINT": f"opc.tcp://127.0.0.1:{sim_port}"},
    )
    driver = mapping.driver.model_copy(
        update={
            "watchdog_interval": 0.3,
            "reconnect": mapping.driver.reconnect.model_copy(update={"initial": 0.1, "max": 0.5}),
        }
    )
    commands = dict(mapping.commands or {})
    for name, seconds in (timeouts or {}).items():
        commands[name] = commands[name].model_copy(update={"timeout": seconds})
    return mapping.model_copy(
        update={
            "driver": driver,
            "jobs": None,
            "copydata": None,
            "commands": commands,
            "mqtt": MachineMqtt(commands=mqtt_commands),
        }
    )


def laser_config(
    state_dir: Path, mapping: MachineMapping, gw_port: int, mqtt: MqttConfig | None = None
) -> Config:
    gateway = GatewayConfig.model_validate(
        {
            "opcua": {"endpoint": f"opc.tcp://127.0.0.1:{gw_port}/cnc-gateway"},
            "state_dir": str(state_dir),
            "inbox": {"enabled": False},
            # These tests command the machine as anonymous OPC UA clients: the gateway file opens that
            # explicitly.
            "access": {"anonymous": "operator"},
        }
    ).model_copy(update={"mqtt": mqtt})
    return Config(gateway, (mapping,), state_dir.parent)


class Events:
    """An asyncua subscription handler that records events."""

    def __init__(self) -> None:
        self.received: list[Any] = []

    def event_notification(self, event: Any) -> None:
        self.received.append(event)

    def of_type(self, type_id: int) -> list[Any]:
        return [e for e in self.received if e.EventType == ua.NodeId(type_id)]

    def alarms(self) -> list[Any]:
        return self.of_type(ua.ObjectIds.AlarmConditionType)


@dataclass
class LaserRig:
    config: Config
    sim: Simulator
    gateway: Gateway | None = None
    clients: list[Client] = field(default_factory=list)
    _run: asyncio.Task[None] | None = None

    @property
    def endpoint(self) -> str:
        return self.config.gateway.opcua.endpoint

    @property
    def machine(self) -> Any:
        assert self.gateway is not None
        return self.gateway.tree.machines[MACHINE]

    async def start_gateway(self) -> None:
        self.gateway = Gateway(self.config)
        await self.gateway.__aenter__()
        self._run = asyncio.create_task(self.gateway.run(), name="test:gateway")
        await wait_until(
            lambda: self.machine.nodes["Machine/State"].sample.good,
            timeout=15,
            message="the gateway to mirror the simulator",
        )

    async def stop_gateway(self) -> None:
        for client in self.clients:
            # Already gone with the server, in whichever way asyncua says so.
            with contextlib.suppress(Exception):
                await client.disconnect()
        self.clients.clear()
        if self._run is not None:
            self._run.cancel()
            await asyncio.gather(self._run, return_exceptions=True)
            self._run = None
        if self.gateway is not None:
            await self.gateway.__aexit__(None, None, None)
            self.gateway = None

    async def client(self) -> Client:
        client = Client(self.endpoint, timeout=5)
        await client.connect()
        self.clients.append(client)
        return client

    async def subscribe_alarms(self, client: Client, source: ua.NodeId | None = None) -> tuple[Any, Events]:
        events = Events()
        sub = await client.create_subscription(20, events)
        await sub.subscribe_alarms_and_conditions(
            source or ua.NodeId(ua.ObjectIds.Server), ua.ObjectIds.AlarmConditionType
        )
        return sub, events

    async def command(self, client: Client, name: str, *args: ua.Variant) -> list[Any]:
        commands = client.get_node(f"ns=2;s={MACHINE}/Commands")
        result = await commands.call_method(f"2:{name}", *args)
        return result if isinstance(result, list) else [result]

    def state(self) -> Any:
        return self.sim.machine.state


@asynccontextmanager
async def laser_rig(
    tmp_path: Path,
    *,
    mqtt: MqttConfig | None = None,
    mqtt_commands: bool = True,
    timeouts: dict[str, float] | None = None,
) -> AsyncIterator[LaserRig]:
    sim_ports = (free_port(), free_port())
    store = tmp_path / "store"
    store.mkdir(exist_ok=True)
    mapping = laser_mapping(sim_ports[0], mqtt_commands=mqtt_commands, timeouts=timeouts)
    config = laser_config(tmp_path / "state", mapping, free_port(), mqtt)
    sim = Simulator(opcua_port=sim_ports[0], ftp_port=sim_ports[1], speed=SPEED, store=store)
    await sim.__aenter__()
    rig = LaserRig(config, sim)
    try:
        await rig.start_gateway()
        yield rig
    finally:
        await rig.stop_gateway()
        await rig.sim.__aexit__(None, None, None)


def text(value: str) -> ua.Variant:
    return ua.Variant(value, ua.VariantType.String)
