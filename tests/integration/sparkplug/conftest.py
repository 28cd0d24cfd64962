"""Sparkplug tests: a real Mosquitto on a free port, the test host (host.py), and the edge node two ways.

- `laser_sparkplug`: the shipped laser-sim mapping, run by a real Gateway against a real simulator;
- `SinkRig`: the Sparkplug sink alone on a tree of its own (no source), for what needs values of
  every type or a controller that answers as told (`Controller`, the tree's Writer seam).
"""

from __future__ import annotations

import asyncio
import uuid
from collections.abc import AsyncIterator, Iterator
from contextlib import asynccontextmanager
from dataclasses import dataclass, field
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

import pytest

from gateway.app import Gateway
from gateway.config.gateway import GatewayConfig
from gateway.config.loader import Config
from gateway.config.mapping import MachineMapping
from gateway.model.sample import ReadBack
from gateway.model.tree import VariableNode, VariableTree
from gateway.sinks.mqtt.config import MachineMqtt, MqttConfig
from gateway.sinks.sparkplug.config import SparkplugConfig
from gateway.sinks.sparkplug.sink import SparkplugSink
from simulator.runner import Simulator
from tests.integration.laser_rig import laser_mapping
from tests.integration.mqtt.conftest import Mosquitto
from tests.integration.sparkplug.host import SparkplugHost
from tests.waiting import free_port, wait_until

MACHINE = "laser-sim"
TYPES = (
    "Boolean",
    "SByte",
    "Byte",
    "Int16",
    "UInt16",
    "Int32",
    "UInt32",
    "Int64",
    "UInt64",
    "Float",
    "Double",
    "String",
    "DateTime",
)


def typed_mapping(machine: str = "m1", *, writable: bool = True, role: str | None = None) -> MachineMapping:
    """A machine with a read-write variable of every type, scalar (`T/<type>`) and array (`A/<type>`)."""
    variables = [
        {
            "path": f"{folder}/{name}",
            "source": f"{folder}.{name}",
            "type": name + suffix,
            "access": "readwrite",
            **({"role": role} if role else {}),
        }
        for name in TYPES
        for folder, suffix in (("T", ""), ("A", "[]"))
    ]
    variables.append(
        {
            "path": "Feed/Override",
            "source": "override",
            "type": "UInt16",
            "unit": "%",
            "access": "readwrite",
            "range": {"min": 0, "max": 150},
        }
    )
    variables.append({"path": "Axes/X/Position", "source": "x", "type": "Double", "unit": "mm"})
    return MachineMapping.model_validate(
        {
            "machine": machine,
            "driver": {"endpoint": "opc.tcp://127.0.0.1:1"},
            "variables": variables,
            "mqtt": {"writable": writable},
        }
    )


@pytest.fixture
def queueing_broker(tmp_path: Path) -> Iterator[Mosquitto]:
    """A Mosquitto that also queues QoS 0 messages for a persistent session while its client is away:
    a host that reconnects after a broker restart then misses nothing the edge node sent meanwhile."""
    broker = Mosquitto(tmp_path / "mosquitto", free_port(), extra="queue_qos0_messages true\n")
    broker.start()
    try:
        yield broker
    finally:
        broker.stop()


@pytest.fixture
def hosts() -> Iterator[list[SparkplugHost]]:
    """Sparkplug hosts a test starts (`start_host`), stopped at its end."""
    made: list[SparkplugHost] = []
    yield made
    for host in made:
        host.stop()


def start_host(hosts: list[SparkplugHost], port: int, **kwargs: Any) -> SparkplugHost:
    host = SparkplugHost(port, **kwargs).start()
    hosts.append(host)
    return host


def sparkplug_config(port: int, **overrides: Any) -> SparkplugConfig:
    """The edge node on the test broker, with fast timings."""
    settings: dict[str, Any] = {
        "broker": {
            "port": port,
            "client_id": f"spb-{uuid.uuid4().hex[:8]}",
            "keepalive": 5,
            "connect_timeout": 2,
            "reconnect": {"initial": 0.05, "max": 0.3},
        }
    }
    settings.update(overrides)
    return SparkplugConfig.model_validate(settings)


def laser_config(
    tmp_path: Path,
    sim_port: int,
    sparkplug: SparkplugConfig,
    *,
    mqtt: MqttConfig | None = None,
    writable: bool = True,
    access: dict[str, Any] | None = None,
) -> Config:
    mapping = laser_mapping(sim_port)
    mapping = mapping.model_copy(update={"mqtt": MachineMqtt(writable=writable, commands=True)})
    gateway = GatewayConfig.model_validate(
        {
            "opcua": {"endpoint": f"opc.tcp://127.0.0.1:{free_port()}/cnc-gateway", "security": ["None"]},
            "state_dir": str(tmp_path / "state"),
            "inbox": {"enabled": False},
            "access": access or {},
        }
    ).model_copy(update={"mqtt": mqtt, "sparkplug": sparkplug})
    return Config(gateway, (mapping,), tmp_path)


@dataclass
class Laser:
    gateway: Gateway
    sim: Simulator | None
    sink: SparkplugSink
    sim_port: int
    store: Path
    loop_program: str | None = None

    @property
    def machine(self) -> Any:
        return self.gateway.tree.machines[MACHINE]

    async def stop_sim(self) -> None:
        sim, self.sim = self.sim, None
        if sim is not None:
            await sim.__aexit__(None, None, None)

    async def start_sim(self) -> None:
        sim = Simulator(
            opcua_port=self.sim_port,
            ftp_port=free_port(),
            speed=20.0,
            store=self.store,
            loop_program=self.loop_program,
        )
        await sim.__aenter__()
        self.sim = sim


@asynccontextmanager
async def laser_sparkplug(
    tmp_path: Path, sparkplug: SparkplugConfig, *, loop_program: str | None = None, **kwargs: Any
) -> AsyncIterator[Laser]:
    """The laser-sim machine from a real simulator through a real Gateway, with the Sparkplug sink."""
    sim_port = free_port()
    store = tmp_path / "store"
    store.mkdir(exist_ok=True)
    gw = Gateway(laser_config(tmp_path, sim_port, sparkplug, **kwargs))
    laser = Laser(gw, None, gw.sink("sparkplug", SparkplugSink), sim_port, store, loop_program)
    await laser.start_sim()
    try:
        async with gw:
            task = asyncio.create_task(gw.run(), name="test:gateway")
            try:
                await wait_until(
                    lambda: laser.machine.status.is_connected, timeout=15, message="the simulator"
                )
                yield laser
            finally:
                task.cancel()
                await asyncio.gather(task, return_exceptions=True)
    finally:
        await laser.stop_sim()


# --- the sink alone ----------------------------------------------------------------------------------


@dataclass
class Controller:
    """The tree's Writer seam, answering like a controller that keeps what it is given (or refuses)."""

    machine: Any
    refuse: set[str] = field(default_factory=set)
    written: list[tuple[str, Any]] = field(default_factory=list)

    async def write(self, node: VariableNode, raw: Any) -> ReadBack | None:
        from gateway.errors import ControllerRefused

        if node.path in self.refuse:
            raise ControllerRefused("the controller says no", status="BadWriteNotSupported")
        self.written.append((node.path, raw))
        return ReadBack(raw, datetime.now(UTC))


@dataclass
class SinkRig:
    tree: VariableTree
    sink: SparkplugSink
    controller: Controller


@asynccontextmanager
async def sink_rig(
    tmp_path: Path, mapping: MachineMapping, sparkplug: SparkplugConfig, *, connected: bool = True
) -> AsyncIterator[SinkRig]:
    """The Sparkplug sink on a tree of `mapping`'s machine, no source: the test ingests values itself."""
    tree = VariableTree([mapping.definition()])
    machine = tree.machines[mapping.machine]
    controller = Controller(machine)
    machine.writer = controller
    if connected:
        machine.status.connected()
    state = tmp_path / "state"
    state.mkdir(exist_ok=True)
    sink = SparkplugSink(tree, sparkplug, sparkplug.connection(None), state, {mapping.machine: mapping})
    async with sink:
        task = asyncio.create_task(sink.run(), name="test:sparkplug")
        try:
            yield SinkRig(tree, sink, controller)
        finally:
            task.cancel()
            await asyncio.gather(task, return_exceptions=True)
