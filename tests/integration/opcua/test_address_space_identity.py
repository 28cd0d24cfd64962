"""Clients cannot tell the address space built in bulk (sinks/opcua/bulk.py) from asyncua's own AddNodes.

Two OPC UA sinks serve one tree: one builds its nodes the old way (through asyncua's
AddNodes, `direct_nodes = False`), the other the new way. A real asyncua client
browses each server recursively from the Objects folder (every reference, both
directions) and reads every attribute of every node it reaches; the two answers
must be equal in every field. The only fields allowed to differ are the ones that
say *when*: server timestamps, and the creation time asyncua stamps on constant
attributes (present on both or on neither). The same comparison runs on the
servers' own records (every node of the gateway's namespace, every reference of
the standard namespace), so that a difference no client happened to reach fails too.
The new one reads its standard namespace from the cache (gateway/shims/asyncua_ns0.py)
that a server started before it wrote, node by node as they are asked for.
"""

from __future__ import annotations

import asyncio
from collections.abc import AsyncIterator, Sequence
from dataclasses import dataclass
from datetime import UTC, datetime
from typing import Any

import pytest
import pytest_asyncio
from asyncua import ua

from gateway.config.loader import load_mapping
from gateway.model.context import WriteContext
from gateway.model.methods import Argument, Method
from gateway.model.tree import VariableTree
from gateway.model.types import TypeSpec
from gateway.shims.asyncua_ns0 import LazyNodes, cache_file
from gateway.sinks.opcua.config import OpcUaServerConfig
from gateway.sinks.opcua.server import OpcUaSink
from tests.opcua_client import Client
from tests.waiting import free_port, wait_until

pytestmark = pytest.mark.asyncio(loop_scope="module")

LASER = """
machine: laser
description: Test laser cutter
driver: {endpoint: "opc.tcp://127.0.0.1:4841"}
variables:
  - {path: Axes/X/Position, source: "ns=2;s=x", type: Double, unit: mm, range: {min: 0, max: 3000},
     description: Actual X position}
  - {path: Axes/X/Target, source: "ns=2;s=xt", type: Double, source_type: Int32,
     scale: {gain: 0.001, offset: 5}, unit: mm, access: readwrite, range: {min: 0, max: 3000}}
  - {path: Axes/Y/Position, source: "ns=2;s=y", type: Double, unit: furlong}
  - {path: Feed/Override, source: "ns=2;s=o", type: UInt16, unit: "%", access: readwrite,
     range: {min: 0, max: 150}}
  - {path: Laser/On, source: "ns=2;s=on", type: Boolean}
  - {path: Laser/PowerTable, source: "ns=2;s=pt", type: "Double[]", unit: "%"}
  - {path: Laser/Counts, source: "ns=2;s=pc", type: "UInt32[]"}
  - {path: Program/Name, source: "ns=2;s=pn", type: String, access: readwrite}
  - {path: Program/Started, source: "ns=2;s=ps", type: DateTime}
  - {path: Program/Block, source: "ns=2;s=pb", type: UInt32}
  - {path: Flat, source: "ns=2;s=flat", type: Int64, description: A variable right under the machine}
"""

PRESS = """
machine: press
description: Test press brake
driver: {endpoint: "opc.tcp://127.0.0.1:4842"}
variables:
  - {path: Axes/X/Position, source: "ns=3;s=x", type: Float, unit: mm}
  - {path: Ram/Force, source: "ns=3;s=f", type: Double, unit: kN, range: {min: -10, max: 10}}
  - {path: Ram/Setpoint, source: "ns=3;s=fs", type: Double, unit: kN, access: readwrite}
  - {path: Mode, source: "ns=3;s=m", type: SByte}
"""

ALL_ATTRIBUTES = list(ua.AttributeIds)
# Values of the standard namespace that say when each server started or what time it is.
CLOCKS = {
    ua.NodeId(i)
    for i in (
        ua.ObjectIds.Server_ServerStatus,
        ua.ObjectIds.Server_ServerStatus_StartTime,
        ua.ObjectIds.Server_ServerStatus_CurrentTime,
        ua.ObjectIds.Server_ServerStatus_BuildInfo,
        ua.ObjectIds.Server_ServerStatus_BuildInfo_BuildDate,
    )
}
TS = datetime(2026, 11, 25, 12, 0, tzinfo=UTC)


async def _select(ctx: WriteContext, args: Sequence[Any]) -> Sequence[Any]:
    return (True,)


SELECT = Method(
    "Commands",
    "select",
    "Select a program",
    (Argument("name", TypeSpec.parse("String"), "program name"), Argument("count", TypeSpec.parse("UInt16"))),
    (Argument("ok", TypeSpec.parse("Boolean")),),
    _select,
)


@dataclass
class Pair:
    tree: VariableTree
    old: OpcUaSink
    new: OpcUaSink


@pytest_asyncio.fixture(scope="module", loop_scope="module")
async def pair(tmp_path_factory: pytest.TempPathFactory) -> AsyncIterator[Pair]:
    folder = tmp_path_factory.mktemp("identity")
    (folder / "laser.yaml").write_text(LASER)
    (folder / "press.yaml").write_text(PRESS)
    tree = VariableTree([load_mapping(folder / name).definition() for name in ("laser.yaml", "press.yaml")])
    tree.machines["laser"].add_method(SELECT)
    old = OpcUaSink(
        tree, OpcUaServerConfig(endpoint=f"opc.tcp://127.0.0.1:{free_port()}/old"), folder / "old"
    )
    old.direct_nodes = False
    cache = folder / "cache"
    writer = OpcUaSink(
        tree, OpcUaServerConfig(endpoint=f"opc.tcp://127.0.0.1:{free_port()}/first"), folder / "first"
    )
    writer.cache_dir = cache
    async with writer:  # the first start builds the standard namespace and writes the cache
        assert cache_file(cache).is_file()
    new = OpcUaSink(
        tree, OpcUaServerConfig(endpoint=f"opc.tcp://127.0.0.1:{free_port()}/new"), folder / "new"
    )
    new.cache_dir = cache
    async with old, new:
        assert isinstance(new.server.iserver.aspace._nodes, LazyNodes)  # read from the cache
        runners = [asyncio.create_task(s.run(), name=f"run-{s.endpoint}") for s in (old, new)]
        laser = tree.machines["laser"]
        laser.ingest(laser.nodes["Axes/X/Position"], 12.5, TS)
        laser.ingest(laser.nodes["Laser/PowerTable"], [1.0, 2.5], TS)
        laser.ingest(laser.nodes["Program/Name"], "part.nc", TS)
        # A late variable (added after start-up) takes the same path in both.
        late = laser.add_internal("Status/Extra", "UInt32", "added late", 7)
        for sink in (old, new):
            await wait_until(lambda s=sink: late in s._vars)  # type: ignore[misc]
        yield Pair(tree, old, new)
        for runner in runners:
            runner.cancel()
        await asyncio.wait(runners)


def _when_free(dv: ua.DataValue, attribute: ua.AttributeIds, sample: bool) -> tuple[Any, ...]:
    """A DataValue without what says when: server time always; source time but for a tree variable's
    Value (the sample's; elsewhere, a property's Value say, it is when the node was made)."""
    exact = sample and attribute == ua.AttributeIds.Value
    source = dv.SourceTimestamp if exact else dv.SourceTimestamp is not None
    return (dv.Value, dv.StatusCode, source, dv.ServerTimestamp is not None, dv.SourcePicoseconds)


async def _walk(client: Client, samples: set[ua.NodeId]) -> dict[ua.NodeId, tuple[list[Any], list[Any]]]:
    """Every node reachable from Objects/Machines: its references (both ways) and all its attributes."""
    start = client.nodes.objects
    machines = await start.get_child(["2:Machines"])
    seen: dict[ua.NodeId, tuple[list[Any], list[Any]]] = {}
    todo = [start.nodeid, machines.nodeid]
    while todo:
        nodeid = todo.pop()
        if nodeid in seen:
            continue
        node = client.get_node(nodeid)
        refs = await node.get_references(ua.ObjectIds.References, ua.BrowseDirection.Both)
        params = ua.ReadParameters()
        params.TimestampsToReturn = ua.TimestampsToReturn.Both
        params.NodesToRead = [ua.ReadValueId(NodeId=nodeid, AttributeId=a) for a in ALL_ATTRIBUTES]
        reads = await client.uaclient.read(params)
        attributes = [
            (attribute, _when_free(dv, attribute, nodeid in samples))
            for attribute, dv in zip(ALL_ATTRIBUTES, reads, strict=True)
        ]
        seen[nodeid] = ([_ref(r) for r in refs], attributes)
        if nodeid.NamespaceIndex == 0 and nodeid != start.nodeid:
            continue  # the standard namespace: compared, not walked
        for ref in refs:
            target = ref.NodeId
            if target.NamespaceIndex != 0 or ref.IsForward:
                todo.append(ua.NodeId(target.Identifier, target.NamespaceIndex, target.NodeIdType))
    return seen


def _ref(ref: ua.ReferenceDescription) -> tuple[Any, ...]:
    return (ref.ReferenceTypeId, ref.IsForward, ref.NodeId, ref.BrowseName, ref.DisplayName, ref.NodeClass,
            ref.TypeDefinition)  # fmt: skip


async def test_a_client_browsing_and_reading_everything_sees_the_same(pair: Pair) -> None:
    async with Client(pair.old.endpoint) as a, Client(pair.new.endpoint) as b:
        samples = {pair.new.node_id(node) for node in pair.tree.nodes()}
        old, new = await _walk(a, samples), await _walk(b, samples)
    ours = [n for n in old if n.NamespaceIndex == 2]
    assert len(ours) > 40  # machines, folders, variables, properties, methods and their arguments
    assert samples <= set(ours)
    assert sorted(old, key=str) == sorted(new, key=str)
    for nodeid, (refs, attributes) in old.items():
        other_refs, other_attributes = new[nodeid]
        assert refs == other_refs, nodeid
        assert attributes == other_attributes, nodeid


async def test_the_servers_records_are_the_same_node_by_node(pair: Pair) -> None:
    old = pair.old.server.iserver.aspace  # AddressSpace: keys(), [], no iteration of its own
    new = pair.new.server.iserver.aspace
    ours = {n for n in old.keys() if n.NamespaceIndex == pair.old.namespace_index}  # noqa: SIM118
    assert ours == {n for n in new.keys() if n.NamespaceIndex == pair.new.namespace_index}  # noqa: SIM118
    assert len(ours) > 40
    samples = {pair.new.node_id(node) for node in pair.tree.nodes()}
    for nodeid in ours:
        a, b = old[nodeid], new[nodeid]
        assert list(a.attributes) == list(b.attributes), nodeid
        for attribute in a.attributes:
            sample = nodeid in samples
            assert _when_free(old.read_attribute_value(nodeid, attribute), attribute, sample) == _when_free(
                new.read_attribute_value(nodeid, attribute), attribute, sample
            ), (nodeid, attribute)
        assert [_ref(r) for r in a.references] == [_ref(r) for r in b.references], nodeid
        assert (a.call is None) == (b.call is None), nodeid
    standard = {n for n in old.keys() if n.NamespaceIndex == 0}  # noqa: SIM118
    assert standard == {n for n in new.keys() if n.NamespaceIndex == 0}  # noqa: SIM118
    assert len(standard) > 5000
    for nodeid in standard:  # built by asyncua's generated code, added by the writer in the new one
        a, b = old[nodeid], new[nodeid]
        assert [_ref(r) for r in a.references] == [_ref(r) for r in b.references], nodeid
        assert list(a.attributes) == list(b.attributes), nodeid
        for attribute in a.attributes:
            if nodeid in CLOCKS and attribute == ua.AttributeIds.Value:
                continue
            assert _when_free(old.read_attribute_value(nodeid, attribute), attribute, False) == _when_free(
                new.read_attribute_value(nodeid, attribute), attribute, False
            ), (nodeid, attribute)


async def test_a_node_asyncua_refuses_is_refused_the_same_way(pair: Pair) -> None:
    """An existing node id, a missing parent: the bulk path hands these to asyncua, which says why."""
    existing = pair.new.node_id(pair.tree.machines["laser"].nodes["Laser/On"])
    item = ua.AddNodesItem(
        ParentNodeId=pair.new.machine_node_id("laser"),
        ReferenceTypeId=ua.NodeId(ua.ObjectIds.HasComponent),
        RequestedNewNodeId=existing,
        BrowseName=ua.QualifiedName("On", 2),
        NodeClass=ua.NodeClass.Variable,
        NodeAttributes=ua.VariableAttributes(DisplayName=ua.LocalizedText("On")),
        TypeDefinition=ua.NodeId(ua.ObjectIds.BaseDataVariableType),
    )
    orphan = ua.AddNodesItem(
        ParentNodeId=ua.NodeId("no/such/parent", 2),
        ReferenceTypeId=ua.NodeId(ua.ObjectIds.HasComponent),
        RequestedNewNodeId=ua.NodeId("orphan", 2),
        BrowseName=ua.QualifiedName("orphan", 2),
        NodeClass=ua.NodeClass.Object,
        NodeAttributes=ua.ObjectAttributes(DisplayName=ua.LocalizedText("orphan")),
        TypeDefinition=ua.NodeId(ua.ObjectIds.BaseObjectType),
    )
    for sink in (pair.old, pair.new):
        results = await sink.server.iserver.isession.add_nodes([item, orphan])
        direct = sink._writer.add_nodes([item, orphan]) if sink._writer is not None else results
        for got in (results, direct):
            assert [r.StatusCode.name for r in got] == ["BadNodeIdExists", "BadParentNodeIdInvalid"]


async def test_a_change_to_one_nodes_shared_or_name_record_stays_with_that_node(pair: Pair) -> None:
    """The bulk-built nodes share their constant records and make their name records when first read
    (shims/asyncua_server.py NodeAttributes); what asyncua then writes to one node is that node's alone,
    and a name record monitored or written keeps its callback and its value."""
    aspace = pair.new.server.iserver.aspace
    laser = pair.tree.machines["laser"]
    one = pair.new.node_id(laser.nodes["Axes/Y/Position"])
    other = pair.new.node_id(laser.nodes["Axes/X/Position"])
    for attribute, value in (
        (ua.AttributeIds.AccessLevel, ua.Variant(3, ua.VariantType.Byte)),
        (
            ua.AttributeIds.DisplayName,
            ua.Variant(ua.LocalizedText("Y, renamed"), ua.VariantType.LocalizedText),
        ),
    ):
        before = aspace.read_attribute_value(other, attribute).Value
        seen: list[Any] = []

        async def callback(handle: int, dv: ua.DataValue, seen: list[Any] = seen) -> None:
            seen.append(dv.Value.Value)

        status, handle = aspace.add_datachange_callback(one, attribute, callback)
        assert status.is_good()
        assert (await aspace.write_attribute_value(one, attribute, ua.DataValue(value))).is_good()
        assert aspace.read_attribute_value(one, attribute).Value == value
        assert aspace.read_attribute_value(other, attribute).Value == before
        assert seen == [value.Value]
        aspace.delete_datachange_callback(handle)
