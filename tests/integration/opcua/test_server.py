"""The OPC UA server sink against a real asyncua client over TCP.

The controller side is a small in-test Writer; the OPC UA side is real: one server
for the module, browsed, subscribed to and written through by a real Client.
"""

from __future__ import annotations

import asyncio
import time
from collections import defaultdict
from collections.abc import AsyncIterator
from dataclasses import dataclass
from datetime import UTC, datetime, timedelta
from pathlib import Path
from typing import Any

import pytest
import pytest_asyncio
from asyncua import Node, ua
from asyncua.ua.uaerrors import UaStatusCodeError

from gateway.config.loader import load_mapping
from gateway.config.mapping import MachineMapping
from gateway.errors import ControllerRefused, ControllerUnavailable, SinkError
from gateway.model.tree import Machine, VariableNode, VariableTree
from gateway.sinks.opcua.config import OpcUaServerConfig
from gateway.sinks.opcua.server import OpcUaSink
from gateway.sinks.opcua.values import unece_unit_id
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
     scale: {gain: 0.001, offset: 5}, unit: mm, access: readwrite, range: {min: 0, max: 3000},
     description: Commanded X}
  - {path: Axes/Y/Position, source: "ns=2;s=y", type: Double, unit: furlong}
  - {path: Feed/Override, source: "ns=2;s=o", type: UInt16, unit: "%", access: readwrite,
     range: {min: 0, max: 150}}
  - {path: Laser/On, source: "ns=2;s=on", type: Boolean}
  - {path: Laser/PowerTable, source: "ns=2;s=pt", type: "Double[]", unit: "%"}
  - {path: Program/Name, source: "ns=2;s=pn", type: String, access: readwrite}
  - {path: Program/Started, source: "ns=2;s=ps", type: DateTime}
  - {path: Program/Block, source: "ns=2;s=pb", type: UInt32}
"""

PRESS = """
machine: press
description: Test press brake
driver: {endpoint: "opc.tcp://127.0.0.1:4842"}
variables:
  - {path: Axes/X/Position, source: "ns=3;s=x", type: Float, unit: mm}
  - {path: Ram/Force, source: "ns=3;s=f", type: Double, unit: kN}
  - {path: Ram/Setpoint, source: "ns=3;s=fs", type: Double, unit: kN, access: readwrite}
  - {path: Ram/Stroke, source: "ns=3;s=st", type: Double}
  - {path: Ram/Count, source: "ns=3;s=c", type: UInt32}
"""

TS = datetime(2026, 11, 21, 12, 0, tzinfo=UTC)


class Writer:
    """The controller side of writes: records them, or refuses with a given error."""

    def __init__(self) -> None:
        self.writes: list[tuple[str, Any]] = []
        self.error: Exception | None = None

    async def write(self, node: VariableNode, raw: Any) -> None:
        if self.error is not None:
            raise self.error
        self.writes.append((node.path, raw))


class Changes:
    """Subscription handler: every DataValue received, per node id."""

    def __init__(self) -> None:
        self.seen: dict[ua.NodeId, list[ua.DataValue]] = defaultdict(list)

    def datachange_notification(self, node: Node, val: Any, data: Any) -> None:
        self.seen[node.nodeid].append(data.monitored_item.Value)

    def latest(self, nodeid: ua.NodeId) -> ua.DataValue | None:
        values = self.seen.get(nodeid)
        return values[-1] if values else None


@dataclass
class Env:
    tree: VariableTree
    sink: OpcUaSink
    client: Client
    laser: Machine
    press: Machine
    writer: Writer
    changes: Changes
    sub: Any

    async def var(self, machine: str, path: str) -> Node:
        names = ["2:Machines", f"2:{machine}", *(f"2:{seg}" for seg in path.split("/"))]
        return await self.client.nodes.objects.get_child(names)

    async def watch(self, node: VariableNode) -> ua.NodeId:
        nodeid = self.sink.node_id(node)
        await self.sub.subscribe_data_change(self.client.get_node(nodeid))
        return nodeid


@pytest_asyncio.fixture(scope="module", loop_scope="module")
async def env(tmp_path_factory: pytest.TempPathFactory) -> AsyncIterator[Env]:
    folder = tmp_path_factory.mktemp("mappings")
    (folder / "laser.yaml").write_text(LASER)
    (folder / "press.yaml").write_text(PRESS)
    tree = VariableTree([load_mapping(folder / name).definition() for name in ("laser.yaml", "press.yaml")])
    writer = Writer()
    tree.machines["laser"].writer = writer
    config = OpcUaServerConfig(endpoint=f"opc.tcp://127.0.0.1:{free_port()}/gateway")
    async with OpcUaSink(tree, config, folder) as sink:
        runner = asyncio.create_task(sink.run(), name="opcua-sink-run")
        async with Client(sink.endpoint) as client:
            changes = Changes()
            sub = await client.create_subscription(20, changes)
            yield Env(
                tree, sink, client, tree.machines["laser"], tree.machines["press"], writer, changes, sub
            )
        runner.cancel()
        await asyncio.wait({runner})
        assert not runner.done() or runner.cancelled(), "the value loop died"


@pytest.fixture
def writer(env: Env) -> Writer:
    env.writer.writes.clear()
    env.writer.error = None
    return env.writer


def code(name: str) -> ua.StatusCode:
    return ua.StatusCode(getattr(ua.StatusCodes, name))


# --- address space ---------------------------------------------------------------------------------


async def test_namespace_is_registered_first(env: Env) -> None:
    assert env.sink.namespace_index == 2
    assert (await env.client.get_namespace_array())[2] == "urn:cnc-gateway"


async def test_variable_attributes_by_browse_path(env: Env) -> None:
    node = await env.var("laser", "Axes/X/Position")
    assert node.nodeid == ua.NodeId("laser/Axes/X/Position", 2)
    assert await node.read_node_class() == ua.NodeClass.Variable
    assert await node.read_data_type() == ua.NodeId(ua.ObjectIds.Double)
    assert await node.read_value_rank() == -1
    assert (
        await node.read_attribute(ua.AttributeIds.AccessLevel)
    ).Value.Value == ua.AccessLevel.CurrentRead.mask
    assert (
        await node.read_attribute(ua.AttributeIds.UserAccessLevel)
    ).Value.Value == ua.AccessLevel.CurrentRead.mask
    assert (await node.read_description()).Text == "Actual X position"
    assert (await node.read_display_name()).Text == "Position"
    assert await node.read_type_definition() == ua.NodeId(ua.ObjectIds.AnalogItemType)

    eu = await (await node.get_child("0:EngineeringUnits")).read_value()
    assert eu.UnitId == unece_unit_id("MMT")
    assert eu.DisplayName.Text == "mm"
    assert eu.NamespaceUri == "http://www.opcfoundation.org/UA/units/un/cefact"
    rng = await (await node.get_child("0:EURange")).read_value()
    assert (rng.Low, rng.High) == (0.0, 3000.0)


async def test_equal_constant_attributes_are_one_object_and_stay_apart_when_set(env: Env) -> None:
    """Memory: the two Double positions share their ValueRank, DataType, ... DataValues (asyncua_tuning.py);
    setting one node's attribute replaces its value only, and clients read each node's own."""
    nodes = env.sink.server.iserver.aspace._nodes
    x = nodes[ua.NodeId("laser/Axes/X/Position", 2)].attributes
    y = nodes[ua.NodeId("laser/Axes/Y/Position", 2)].attributes
    for attribute in (
        ua.AttributeIds.ValueRank,
        ua.AttributeIds.DataType,
        ua.AttributeIds.AccessLevel,
        ua.AttributeIds.WriteMask,
        ua.AttributeIds.Historizing,
    ):
        assert x[attribute].value is y[attribute].value, attribute.name
    target = nodes[ua.NodeId("laser/Axes/X/Target", 2)].attributes
    assert x[ua.AttributeIds.AccessLevel].value is not target[ua.AttributeIds.AccessLevel].value  # not equal
    shared = y[ua.AttributeIds.MinimumSamplingInterval].value
    await env.sink.server.write_attribute_value(
        ua.NodeId("laser/Axes/X/Position", 2),
        ua.DataValue(ua.Variant(250.0, ua.VariantType.Double)),
        ua.AttributeIds.MinimumSamplingInterval,
    )
    try:
        assert y[ua.AttributeIds.MinimumSamplingInterval].value is shared
        read = await env.client.read_attributes(
            [await env.var("laser", "Axes/X/Position"), await env.var("laser", "Axes/Y/Position")],
            ua.AttributeIds.MinimumSamplingInterval,
        )
        assert [dv.Value.Value for dv in read] == [250.0, shared.Value.Value]
    finally:
        x[ua.AttributeIds.MinimumSamplingInterval].value = shared


async def test_a_shared_constant_record_is_copied_before_one_node_changes(env: Env) -> None:
    """The constant attributes of equal variables are one record (bulk.py); a client monitoring one node's
    AccessLevel, and a change to another's, each touch their own node only (shims/asyncua_server.py)."""
    nodes = env.sink.server.iserver.aspace._nodes
    force = nodes[ua.NodeId("press/Ram/Force", 2)].attributes
    setpoint_id = ua.NodeId("press/Ram/Setpoint", 2)
    position = nodes[ua.NodeId("press/Axes/X/Position", 2)].attributes
    assert force[ua.AttributeIds.Historizing] is position[ua.AttributeIds.Historizing]  # one shared record
    changes = Changes()
    sub = await env.client.create_subscription(20, changes)
    try:
        force_node = await env.var("press", "Ram/Force")
        await sub.subscribe_data_change(force_node, attr=ua.AttributeIds.Historizing)
        await wait_until(lambda: changes.latest(force_node.nodeid), message="the first Historizing")
        assert force[ua.AttributeIds.Historizing] is not position[ua.AttributeIds.Historizing]  # its own now
        before = nodes[setpoint_id].attributes[ua.AttributeIds.Historizing]
        await env.sink.server.write_attribute_value(
            ua.NodeId("press/Axes/X/Position", 2),
            ua.DataValue(ua.Variant(True, ua.VariantType.Boolean)),
            ua.AttributeIds.Historizing,
        )
        assert nodes[setpoint_id].attributes[ua.AttributeIds.Historizing] is before  # untouched, still shared
        read = await env.client.read_attributes(
            [await env.var("press", "Axes/X/Position"), force_node, await env.var("press", "Ram/Setpoint")],
            ua.AttributeIds.Historizing,
        )
        assert [dv.Value.Value for dv in read] == [True, False, False]
        assert [dv.Value.Value for dv in changes.seen[force_node.nodeid]] == [False]  # not told of the other
    finally:
        await sub.delete()


async def test_writable_variable_and_unknown_unit(env: Env) -> None:
    target = await env.var("laser", "Axes/X/Target")
    read_write = ua.AccessLevel.CurrentRead.mask | ua.AccessLevel.CurrentWrite.mask
    assert (await target.read_attribute(ua.AttributeIds.AccessLevel)).Value.Value == read_write
    assert (await target.read_attribute(ua.AttributeIds.UserAccessLevel)).Value.Value == read_write
    y = await env.var("laser", "Axes/Y/Position")
    eu = await (await y.get_child("0:EngineeringUnits")).read_value()
    assert (eu.UnitId, eu.DisplayName.Text) == (-1, "furlong")
    block = await env.var("laser", "Program/Block")
    assert await block.read_type_definition() == ua.NodeId(ua.ObjectIds.BaseDataVariableType)
    assert await block.read_data_type() == ua.NodeId(ua.ObjectIds.UInt32)


async def test_array_variable_shape(env: Env) -> None:
    table = await env.var("laser", "Laser/PowerTable")
    assert await table.read_value_rank() == 1
    assert await table.read_array_dimensions() == [0]


async def test_folders_machine_objects_and_status_object(env: Env) -> None:
    machines = await env.client.nodes.objects.get_child("2:Machines")
    assert await machines.read_type_definition() == ua.NodeId(ua.ObjectIds.FolderType)
    names = sorted([(await child.read_browse_name()).Name for child in await machines.get_children()])
    assert names == ["laser", "press"]

    laser = await machines.get_child("2:laser")
    assert laser.nodeid == env.sink.machine_node_id("laser")
    assert await laser.read_node_class() == ua.NodeClass.Object
    assert await laser.read_type_definition() == ua.NodeId(ua.ObjectIds.BaseObjectType)
    assert (await laser.read_description()).Text == "Test laser cutter"

    axes = await laser.get_child("2:Axes")
    assert axes.nodeid == ua.NodeId("laser/Axes", 2)
    assert await axes.read_type_definition() == ua.NodeId(ua.ObjectIds.FolderType)

    status = await laser.get_child("2:Status")
    assert await status.read_node_class() == ua.NodeClass.Object
    assert await status.read_type_definition() == ua.NodeId(ua.ObjectIds.BaseObjectType)
    children = {(await c.read_browse_name()).Name for c in await status.get_children()}
    assert children == {"Connected", "State", "LastError", "ReconnectCount", "LastChange", "Endpoint"}
    endpoint = await status.get_child("2:Endpoint")
    assert await endpoint.read_value() == "opc.tcp://127.0.0.1:4841"
    assert await (await status.get_child("2:State")).read_value() == "disconnected"


async def test_two_machines_side_by_side(env: Env) -> None:
    laser_x = await env.var("laser", "Axes/X/Position")
    press_x = await env.var("press", "Axes/X/Position")
    assert laser_x.nodeid != press_x.nodeid
    assert await press_x.read_data_type() == ua.NodeId(ua.ObjectIds.Float)
    env.press.ingest(env.press.nodes["Ram/Force"], 120.5, TS)
    force = await env.var("press", "Ram/Force")
    assert await wait_until(lambda: _read_value(force), message="press force") == 120.5
    press_endpoint = await env.var("press", "Status/Endpoint")
    assert await press_endpoint.read_value() == "opc.tcp://127.0.0.1:4842"


async def _read_value(node: Node) -> Any:
    dv = await node.read_data_value(raise_on_bad_status=False)
    return dv.Value.Value if dv.StatusCode.is_good() else None


# --- values ----------------------------------------------------------------------------------------


async def test_before_any_data_the_value_waits_for_initial_data(env: Env) -> None:
    untouched = await env.var("press", "Axes/X/Position")  # no test feeds it
    dv = await untouched.read_data_value(raise_on_bad_status=False)
    assert dv.StatusCode == code("BadWaitingForInitialData")


async def test_ingested_value_reaches_subscriber_with_source_timestamp(env: Env) -> None:
    node = env.laser.nodes["Axes/X/Position"]
    nodeid = await env.watch(node)
    ts = TS + timedelta(seconds=1)
    env.laser.ingest(node, 1234.5, ts)
    dv = await wait_until(
        lambda: (d := env.changes.latest(nodeid)) and d.Value.Value == 1234.5 and d, message="X position"
    )
    assert dv.StatusCode == code("Good")
    assert dv.SourceTimestamp == ts
    assert dv.ServerTimestamp is not None


async def test_invalidate_turns_the_value_bad_not_connected(env: Env) -> None:
    node = env.laser.nodes["Laser/On"]
    nodeid = await env.watch(node)
    env.laser.ingest(node, True, TS)
    await wait_until(lambda: (d := env.changes.latest(nodeid)) and d.Value.Value is True, message="laser on")
    env.laser.invalidate("BadNotConnected", "controller unreachable")
    dv = await wait_until(
        lambda: (d := env.changes.latest(nodeid)) and d.StatusCode == code("BadNotConnected") and d,
        message="BadNotConnected",
    )
    assert dv.StatusCode.is_bad()
    env.laser.ingest(node, False, TS + timedelta(seconds=2))
    dv = await wait_until(
        lambda: (d := env.changes.latest(nodeid)) and d.StatusCode.is_good() and d, message="good again"
    )
    assert dv.Value.Value is False


async def test_arrays_datetimes_and_strings(env: Env) -> None:
    table = env.laser.nodes["Laser/PowerTable"]
    started = env.laser.nodes["Program/Started"]
    name = env.laser.nodes["Program/Name"]
    ids = [await env.watch(n) for n in (table, started, name)]
    when = datetime(2026, 11, 20, 8, 30, 15, 250000, tzinfo=UTC)
    env.laser.ingest(table, [10.0, 55.5, 100.0], TS)
    env.laser.ingest(started, when, TS)
    env.laser.ingest(name, "bracket.nc", TS)
    await wait_until(
        lambda: (d := env.changes.latest(ids[0])) and d.Value.Value == [10.0, 55.5, 100.0], message="array"
    )
    dv = env.changes.latest(ids[0])
    assert dv.Value.VariantType == ua.VariantType.Double and dv.Value.is_array
    await wait_until(lambda: (d := env.changes.latest(ids[1])) and d.Value.Value == when, message="datetime")
    assert env.changes.latest(ids[1]).Value.VariantType == ua.VariantType.DateTime
    await wait_until(
        lambda: (d := env.changes.latest(ids[2])) and d.Value.Value == "bracket.nc", message="string"
    )


async def test_scaling_is_visible_to_the_client(env: Env) -> None:
    node = env.laser.nodes["Axes/X/Target"]
    nodeid = await env.watch(node)
    env.laser.ingest(node, 250000, TS)  # raw counts: 250000 * 0.001 + 5 = 255 mm
    dv = await wait_until(
        lambda: (d := env.changes.latest(nodeid)) and d.Value.Value == 255.0 and d, message="scaled"
    )
    assert dv.Value.VariantType == ua.VariantType.Double


async def test_a_value_that_does_not_fit_is_bad_type_mismatch_and_the_loop_goes_on(env: Env) -> None:
    node = env.laser.nodes["Program/Block"]
    nodeid = await env.watch(node)
    env.laser.ingest(node, "not a number", TS)  # a misbehaving driver
    await wait_until(
        lambda: (d := env.changes.latest(nodeid)) and d.StatusCode == code("BadTypeMismatch"),
        message="mismatch",
    )
    env.laser.ingest(node, 42, TS + timedelta(seconds=1))
    dv = await wait_until(
        lambda: (d := env.changes.latest(nodeid)) and d.StatusCode.is_good() and d, message="recovered"
    )
    assert dv.Value.Value == 42 and dv.Value.VariantType == ua.VariantType.UInt32


class WriteCounter:
    """Counts asyncua's address-space writes per node id: the sink's update path for monitored nodes."""

    def __init__(self, sink: OpcUaSink) -> None:
        self.aspace = sink.server.iserver.aspace
        self.original = self.aspace.write_attribute_value
        self.calls: dict[ua.NodeId, int] = defaultdict(int)

    async def __call__(self, nodeid: ua.NodeId, *args: Any, **kwargs: Any) -> Any:
        self.calls[nodeid] += 1
        return await self.original(nodeid, *args, **kwargs)

    def __enter__(self) -> WriteCounter:
        self.aspace.write_attribute_value = self
        return self

    def __exit__(self, *exc: object) -> None:
        del self.aspace.write_attribute_value  # the instance's own: the class's again


async def test_a_variable_nobody_monitors_is_not_written_to_asyncua_and_reads_its_latest_value(
    env: Env,
) -> None:
    node = env.press.nodes["Ram/Stroke"]
    nodeid = env.sink.node_id(node)
    stroke = await env.var("press", "Ram/Stroke")
    with WriteCounter(env.sink) as writes:
        for i in range(1, 4):
            env.press.ingest(node, float(i), TS + timedelta(seconds=i))
        assert await wait_until(lambda: _read_value(stroke), message="latest stroke") == 3.0
        dv = await stroke.read_data_value()
        assert dv.SourceTimestamp == TS + timedelta(seconds=3)
        assert dv.ServerTimestamp is not None
        assert dv.Value.VariantType == ua.VariantType.Double
        env.press.ingest(node, None, TS + timedelta(seconds=4), "BadNotConnected", "unplugged")
        dv = await wait_until(
            lambda: _read_bad(stroke, "BadNotConnected"), message="a bad status, read without a subscriber"
        )
        assert dv.Value.Value is None and dv.SourceTimestamp == TS + timedelta(seconds=4)
    assert writes.calls[nodeid] == 0  # no DataValue written, no asyncua write path: nobody would see it
    held = env.sink.server.iserver.aspace._nodes[nodeid].attributes[ua.AttributeIds.Value]
    assert held.value is None and held.value_callback is not None  # asyncua asks the sink on a Read


async def test_a_client_that_subscribes_later_gets_the_current_value_at_once(env: Env) -> None:
    node = env.press.nodes["Ram/Count"]
    nodeid = env.sink.node_id(node)
    count = await env.var("press", "Ram/Count")
    env.press.ingest(node, "not a number", TS)  # a misbehaving driver, while nobody watches
    await wait_until(
        lambda: _read_bad(count, "BadTypeMismatch"), message="mismatch, read without a subscriber"
    )
    env.press.ingest(node, 7, TS + timedelta(seconds=1))
    assert await wait_until(lambda: _read_value(count), message="count 7") == 7
    changes = Changes()
    sub = await env.client.create_subscription(20, changes)
    try:
        with WriteCounter(env.sink) as writes:
            handle = await sub.subscribe_data_change(count)
            first = await wait_until(lambda: changes.latest(nodeid), message="the first notification")
            assert first.Value.Value == 7 and first.SourceTimestamp == TS + timedelta(
                seconds=1
            )  # no change needed
            env.press.ingest(node, 8, TS + timedelta(seconds=2))
            await wait_until(lambda: (d := changes.latest(nodeid)) and d.Value.Value == 8, message="count 8")
            assert writes.calls[nodeid] == 1  # monitored: asyncua's own update path
            await sub.unsubscribe(handle)
            env.press.ingest(node, 9, TS + timedelta(seconds=3))
            assert await wait_until(lambda: _read_value(count), message="count 9") == 9
            assert writes.calls[nodeid] == 1  # nobody monitors it again
        assert [dv.Value.Value for dv in changes.seen[nodeid]] == [7, 8]
    finally:
        await sub.delete()


async def _read_bad(node: Node, status: str) -> ua.DataValue | None:
    dv = await node.read_data_value(raise_on_bad_status=False)
    return dv if dv.StatusCode == code(status) else None


async def test_status_variables_follow_the_machine(env: Env) -> None:
    state = await env.var("laser", "Status/State")
    nodeid = await env.watch(env.laser.status.state_node)
    env.laser.status.connected()
    await wait_until(
        lambda: (d := env.changes.latest(nodeid)) and d.Value.Value == "connected", message="state"
    )
    assert await state.read_value() == "connected"


async def test_internal_variables_added_later_appear_under_their_object(env: Env) -> None:
    node = env.laser.add_internal("Jobs/Queued", "UInt32", "Jobs waiting for delivery", 3)
    queued = await wait_until(lambda: _try_child(env, "laser", "Jobs/Queued"), message="Jobs/Queued")
    assert await wait_until(lambda: _read_value(queued)) == 3
    jobs = await env.var("laser", "Jobs")
    assert await jobs.read_type_definition() == ua.NodeId(ua.ObjectIds.BaseObjectType)
    assert queued.nodeid == env.sink.node_id(node)


async def _try_child(env: Env, machine: str, path: str) -> Node | None:
    try:
        return await env.var(machine, path)
    except UaStatusCodeError:
        return None


# --- writes ----------------------------------------------------------------------------------------


async def _write(node: Node, variant: ua.Variant) -> ua.StatusCode:
    params = ua.WriteParameters()
    params.NodesToWrite = [
        ua.WriteValue(NodeId=node.nodeid, AttributeId=ua.AttributeIds.Value, Value=ua.DataValue(variant))
    ]
    return (await node.session.write(params))[0]


async def test_accepted_write_reaches_the_controller_unscaled(env: Env, writer: Writer) -> None:
    target = await env.var("laser", "Axes/X/Target")
    before = await target.read_data_value(raise_on_bad_status=False)
    await target.write_value(ua.Variant(105.0, ua.VariantType.Double))
    assert writer.writes == [("Axes/X/Target", 100000)]  # (105 - 5) / 0.001
    after = await target.read_data_value(raise_on_bad_status=False)
    assert after.Value == before.Value, "the value only changes when the controller reports it"


async def test_write_of_uint16_and_string(env: Env, writer: Writer) -> None:
    override = await env.var("laser", "Feed/Override")
    name = await env.var("laser", "Program/Name")
    assert await _write(override, ua.Variant(80, ua.VariantType.UInt16)) == code("Good")
    assert await _write(name, ua.Variant("part.nc", ua.VariantType.String)) == code("Good")
    assert writer.writes == [("Feed/Override", 80), ("Program/Name", "part.nc")]


async def test_read_only_variable_is_bad_not_writable(env: Env, writer: Writer) -> None:
    position = await env.var("laser", "Axes/X/Position")
    assert await _write(position, ua.Variant(1.0, ua.VariantType.Double)) == code("BadNotWritable")
    connected = await env.var("laser", "Status/Connected")
    assert await _write(connected, ua.Variant(True, ua.VariantType.Boolean)) == code("BadNotWritable")
    assert writer.writes == []


async def test_wrong_variant_type_is_bad_type_mismatch(env: Env, writer: Writer) -> None:
    override = await env.var("laser", "Feed/Override")
    target = await env.var("laser", "Axes/X/Target")
    assert await _write(override, ua.Variant(80.0, ua.VariantType.Double)) == code("BadTypeMismatch")
    assert await _write(override, ua.Variant(80, ua.VariantType.Int32)) == code("BadTypeMismatch")
    assert await _write(target, ua.Variant([1.0, 2.0], ua.VariantType.Double)) == code("BadTypeMismatch")
    with pytest.raises(UaStatusCodeError) as raised:
        await target.write_value(ua.Variant(1.0, ua.VariantType.Float))
    assert raised.value.code == ua.StatusCodes.BadTypeMismatch
    assert writer.writes == []


async def test_out_of_range_is_bad_out_of_range(env: Env, writer: Writer) -> None:
    override = await env.var("laser", "Feed/Override")
    assert await _write(override, ua.Variant(151, ua.VariantType.UInt16)) == code("BadOutOfRange")
    assert writer.writes == []


async def test_controller_refusal_and_unavailability_are_reported(env: Env, writer: Writer) -> None:
    name = await env.var("laser", "Program/Name")
    writer.error = ControllerRefused("program is running", status="BadInvalidState")
    assert await _write(name, ua.Variant("x.nc", ua.VariantType.String)) == code("BadInvalidState")
    writer.error = ControllerUnavailable("link down")
    assert await _write(name, ua.Variant("x.nc", ua.VariantType.String)) == code("BadNotConnected")
    assert writer.writes == []


async def test_machine_without_controller_connection_is_bad_not_connected(env: Env) -> None:
    assert env.press.writer is None
    setpoint = await env.var("press", "Ram/Setpoint")
    assert await _write(setpoint, ua.Variant(50.0, ua.VariantType.Double)) == code("BadNotConnected")


async def test_other_attributes_and_non_variables_are_not_writable(env: Env, writer: Writer) -> None:
    target = await env.var("laser", "Axes/X/Target")
    with pytest.raises(UaStatusCodeError) as raised:
        await target.write_attribute(
            ua.AttributeIds.DisplayName, ua.DataValue(ua.Variant(ua.LocalizedText("Y")))
        )
    assert raised.value.code == ua.StatusCodes.BadNotWritable
    axes = await env.var("laser", "Axes")
    with pytest.raises(UaStatusCodeError) as raised:
        await axes.write_attribute(
            ua.AttributeIds.Description, ua.DataValue(ua.Variant(ua.LocalizedText("x")))
        )
    assert raised.value.code == ua.StatusCodes.BadNotWritable
    eu = await target.get_child("0:EngineeringUnits")
    assert await _write(eu, ua.Variant(ua.EUInformation(), ua.VariantType.ExtensionObject)) == code(
        "BadNotWritable"
    )
    assert (await target.read_display_name()).Text == "Target"
    assert writer.writes == []


async def test_several_writes_in_one_request_are_answered_each(env: Env, writer: Writer) -> None:
    override = await env.var("laser", "Feed/Override")
    position = await env.var("laser", "Axes/X/Position")
    params = ua.WriteParameters()
    params.NodesToWrite = [
        ua.WriteValue(NodeId=n.nodeid, AttributeId=ua.AttributeIds.Value, Value=ua.DataValue(v))
        for n, v in [
            (override, ua.Variant(90, ua.VariantType.UInt16)),
            (position, ua.Variant(1.0, ua.VariantType.Double)),
            (override, ua.Variant(200, ua.VariantType.UInt16)),
        ]
    ]
    results = await env.client.uaclient.write(params)
    assert results == [code("Good"), code("BadNotWritable"), code("BadOutOfRange")]
    assert writer.writes == [("Feed/Override", 90)]


async def test_writes_to_other_nodes_keep_asyncua_behaviour(env: Env) -> None:
    server_status = env.client.get_node(ua.NodeId(ua.ObjectIds.Server_ServerStatus_State))
    with pytest.raises(UaStatusCodeError) as raised:
        await server_status.write_value(ua.Variant(0, ua.VariantType.Int32))
    assert raised.value.code == ua.StatusCodes.BadUserAccessDenied


# --- start-up ----------------------------------------------------------------------------------------


async def test_port_in_use_is_a_sink_error(env: Env, tmp_path: Path) -> None:
    config = OpcUaServerConfig(endpoint=env.sink.endpoint)
    with pytest.raises(SinkError, match="cannot listen"):
        async with OpcUaSink(VariableTree(), config, tmp_path):
            pass


def _big_mapping(index: int, count: int) -> MachineMapping:
    units = ["mm", "W", "", "bar", "mm/min"]
    variables: list[dict[str, Any]] = []
    for v in range(count):
        var: dict[str, Any] = {
            "path": f"Group{v // 250}/Sub{(v // 25) % 10}/Var{v % 25}",
            "source": f"ns=2;s=v{v}",
            "type": "Double" if v % 3 else "Int32",
        }
        if units[v % 5]:
            var["unit"] = units[v % 5]
        if v % 4 == 0:
            var["range"] = {"min": 0, "max": 100}
        variables.append(var)
    return MachineMapping.model_validate(
        {
            "machine": f"m{index:02d}",
            "driver": {"endpoint": "opc.tcp://127.0.0.1:4841"},
            "variables": variables,
        }
    )


async def test_ten_thousand_variables_over_twenty_machines(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    tree = VariableTree([_big_mapping(i, 500).definition() for i in range(20)])
    config = OpcUaServerConfig(endpoint=f"opc.tcp://127.0.0.1:{free_port()}/big")
    started = time.perf_counter()
    async with OpcUaSink(tree, config, tmp_path) as sink:
        elapsed = time.perf_counter() - started
        mapped = sum(1 for n in tree.nodes() if not n.internal)
        with capsys.disabled():
            print(f"\nOPC UA sink: {mapped} mapped variables over 20 machines started in {elapsed:.2f} s")
        async with Client(sink.endpoint) as client:
            node = await client.nodes.objects.get_child(
                ["2:Machines", "2:m19", "2:Group1", "2:Sub9", "2:Var24"]
            )
            assert node.nodeid == ua.NodeId("m19/Group1/Sub9/Var24", 2)
            assert await node.read_data_type() == ua.NodeId(ua.ObjectIds.Double)
    assert mapped == 10_000
