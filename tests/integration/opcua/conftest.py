"""A small real OPC UA server standing in for a controller, on a free loopback port.

It can be stopped and started again on the same port, which is what the
reconnect tests need and what a shared simulator could not offer.
"""

from __future__ import annotations

import asyncio
from collections.abc import AsyncIterator
from datetime import UTC, datetime
from typing import Any

import pytest
from asyncua import Server, ua

from gateway.config.mapping import MachineMapping
from gateway.model.tree import Machine
from gateway.sources.opcua.client import OpcUaSource
from tests.trees import MappedTree
from tests.waiting import free_port

NS_URI = "urn:cnc-gateway:test-controller"
SOURCE_TS = datetime(2024, 5, 6, 7, 8, 9, 123000, tzinfo=UTC)

# (browse name, node id string within our namespace, initial value, variant type, writable)
SCALARS = [
    ("ActPos", "s=::AsGlobalPV:gAxisX.ActPos", 12.5, ua.VariantType.Double, False),
    ("Override", "s=::AsGlobalPV:gFeed.Override", 100, ua.VariantType.UInt16, True),
    ("ProgramName", "s=::AsGlobalPV:gProgram.Name", "part.nc", ua.VariantType.String, False),
    ("AlarmIds", "s=::AsGlobalPV:gAlarms.Ids", [3, 7], ua.VariantType.UInt32, False),
    (
        "Clock",
        "s=::AsGlobalPV:gClock",
        datetime(2024, 1, 2, 3, 4, 5, tzinfo=UTC),
        ua.VariantType.DateTime,
        True,
    ),
    ("Counter", "i=1001", -5, ua.VariantType.Int32, True),
]


class Controller:
    """An asyncua server with a few B&R-style variables, restartable on the same port."""

    def __init__(self, port: int) -> None:
        self.port = port
        self.endpoint = f"opc.tcp://127.0.0.1:{port}/controller"
        self.server: Server | None = None
        self.ns = 0
        self.nodes: dict[str, Any] = {}

    async def build(self) -> None:
        server = Server()
        await server.init()
        server.set_endpoint(self.endpoint)
        server.set_security_policy([ua.SecurityPolicyType.NoSecurity])
        await server.register_namespace("urn:cnc-gateway:another-namespace")  # so ours is not at index 2
        self.ns = ns = await server.register_namespace(NS_URI)
        machine = await server.nodes.objects.add_object(
            ua.NodeId("Machine", ns), ua.QualifiedName("Machine", ns)
        )
        for name, ident, value, vtype, writable in SCALARS:
            node_id = ua.NodeId.from_string(f"ns={ns};{ident}")
            node = await machine.add_variable(node_id, ua.QualifiedName(name, ns), ua.Variant(value, vtype))
            if writable:
                await node.set_writable()
            self.nodes[name] = node
        pos = self.nodes["ActPos"]
        await pos.add_property(
            ua.NodeId("ActPos.EU", ns), ua.QualifiedName("EngineeringUnits", 0),
            ua.EUInformation(DisplayName=ua.LocalizedText("mm"), Description=ua.LocalizedText("millimetre")),
        )  # fmt: skip
        await pos.add_property(
            ua.NodeId("ActPos.EURange", ns), ua.QualifiedName("EURange", 0), ua.Range(Low=0.0, High=3000.0)
        )
        await pos.write_attribute(
            ua.AttributeIds.Description, ua.DataValue(ua.Variant(ua.LocalizedText("Actual X position")))
        )
        # A B&R structure: a variable of a structured type whose members are component variables.
        g_axis = await machine.add_variable(
            ua.NodeId("::AsGlobalPV:gAxis", ns),
            ua.QualifiedName("gAxis", ns),
            0,
            datatype=ua.NodeId(ua.ObjectIds.Structure),
        )
        await g_axis.add_variable(
            ua.NodeId("::AsGlobalPV:gAxis.ActPos", ns), ua.QualifiedName("ActPos", ns), 1.0
        )
        await g_axis.add_variable(
            ua.NodeId("::AsGlobalPV:gAxis.Referenced", ns), ua.QualifiedName("Referenced", ns), True
        )
        # A plain variable that also has a member: its own value must not clash with the member's path.
        spindle = await machine.add_variable(ua.NodeId("Spindle", ns), ua.QualifiedName("Spindle", ns), 0.0)
        await spindle.add_variable(ua.NodeId("Spindle.Override", ns), ua.QualifiedName("Override", ns), 100.0)
        # Names that need cleaning, clash after cleaning, or are reserved by the gateway.
        status = await machine.add_object(ua.NodeId("Status", ns), ua.QualifiedName("Status", ns))
        await status.add_variable(ua.NodeId("Status.Temp", ns), ua.QualifiedName("Temp °C [1]", ns), 21.5)
        await machine.add_variable(ua.NodeId("a b", ns), ua.QualifiedName("a b", ns), 1)
        await machine.add_variable(ua.NodeId("a_b", ns), ua.QualifiedName("a_b", ns), 2)
        await machine.add_variable(
            ua.NodeId("Blob", ns),
            ua.QualifiedName("Blob", ns),
            ua.Variant(b"\x00\x01", ua.VariantType.ByteString),
        )
        self.server = server
        await self.set("ActPos", 12.5)

    async def start(self) -> None:
        assert self.server is not None
        await self.server.start()

    async def stop(self) -> None:
        """Stop listening and drop every client connection, as a controller being switched off does."""
        assert self.server is not None
        task = self.server.iserver.time_task
        if task is not None:  # its 1 s sleep would otherwise make every stop take a second
            task.cancel()
            await asyncio.gather(task, return_exceptions=True)
            self.server.iserver.time_task = None
        await self.server.stop()

    async def set(self, name: str, value: Any, source_ts: datetime = SOURCE_TS) -> None:
        node = self.nodes[name]
        vtype = await node.read_data_type_as_variant_type()
        await node.write_value(ua.DataValue(ua.Variant(value, vtype), SourceTimestamp=source_ts))

    async def get(self, name: str) -> Any:
        return await self.nodes[name].read_value()

    def source(self, name: str) -> str:
        ident = next(i for n, i, *_ in SCALARS if n == name)
        return f"ns={self.ns};{ident}"


@pytest.fixture
async def controller() -> AsyncIterator[Controller]:
    ctl = Controller(free_port())
    await ctl.build()
    await ctl.start()
    try:
        yield ctl
    finally:
        await ctl.stop()


def make_machine(endpoint: str, variables: list[dict[str, Any]], **driver: Any) -> Machine:
    """A one-machine tree with fast timings, so loss and reconnect tests stay short."""
    settings = {
        "endpoint": endpoint,
        "timeout": 2,
        "watchdog_interval": 0.3,
        "reconnect": {"initial": 0.1, "max": 0.4},
    }
    settings.update(driver)
    mapping = MachineMapping.model_validate({"machine": "cell-1", "driver": settings, "variables": variables})
    return MappedTree([mapping]).machines["cell-1"]


def source_for(machine: Machine) -> OpcUaSource:
    """The OPC UA source of a machine made by `make_machine`, with its mapping's driver settings."""
    tree = machine.tree
    assert isinstance(tree, MappedTree)
    return OpcUaSource(machine, tree.mappings[machine.name])
