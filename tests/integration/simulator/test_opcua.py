"""The simulator over the wire: a real asyncua client and real FTP clients against a running Simulator."""

from __future__ import annotations

from collections.abc import AsyncIterator
from datetime import UTC, datetime, timedelta
from typing import Any

import aioftp
import pytest
from asyncua import ua
from asyncua.ua.uaerrors import UaStatusCodeError

from simulator.runner import Simulator
from tests.opcua_client import Client
from tests.waiting import free_port, wait_until

G = "ns=2;s=::AsGlobalPV:"


@pytest.fixture
async def client(sim: Simulator) -> AsyncIterator[Client]:
    async with Client(sim.opcua_endpoint, timeout=5) as c:
        yield c


async def read(client: Client, name: str) -> Any:
    node_id = name if name.startswith("ns=") else G + name
    return await client.get_node(node_id).read_value()


async def write(client: Client, name: str, value: Any, vtype: ua.VariantType) -> None:
    await client.get_node(G + name).write_value(ua.Variant(value, vtype))


async def refused(client: Client, name: str, value: Any, vtype: ua.VariantType) -> str:
    with pytest.raises(UaStatusCodeError) as info:
        await write(client, name, value, vtype)
    return ua.status_codes.get_name_and_doc(info.value.code)[0]


B, U16, I16, I32, S, D = (
    ua.VariantType.Boolean,
    ua.VariantType.UInt16,
    ua.VariantType.Int16,
    ua.VariantType.Int32,
    ua.VariantType.String,
    ua.VariantType.Double,
)

JOB = "G21 G90\nG0 X10 Y10\nG1 X300 F600\nG1 Y100\nM30\n"


async def test_uploaded_program_runs_and_values_move(sim: Simulator, client: Client) -> None:
    async with aioftp.Client.context("127.0.0.1", sim.ftp_port, sim.ftp_user, sim.ftp_password) as ftp:
        async with ftp.upload_stream("/DATA/Programs/.job.tmp") as stream:
            await stream.write(JOB.encode())
        await ftp.rename("/DATA/Programs/.job.tmp", "/DATA/Programs/job.nc")
    await write(client, "gCmd.SelectProgram", "job.nc", S)
    assert await read(client, "gProgram.Name") == "job.nc"
    await write(client, "gCmd.Start", True, B)
    assert await read(client, "gMachine.State") == 1  # takes effect at once
    assert await read(client, "gMachine.StateText") == "Running"

    await wait_until(lambda: read(client, "gProgram.Block"), message="a block to run")
    await wait_until(lambda: _gt(read(client, "gAxis[0].ActPos"), 50.0), message="X to move past 50")
    assert await read(client, "gAxis[1].ActPos") == pytest.approx(10.0)
    assert await read(client, "gProgram.BlockText") == "G1 X300 F600"
    assert await read(client, "gProgram.Block") == 3
    assert await read(client, "gAxis[0].CmdPos") == pytest.approx(300.0)
    assert await read(client, "gFeed.Act") == pytest.approx(600.0)

    await write(client, "gFeed.Override", 50, U16)
    await wait_until(lambda: _eq(read(client, "gFeed.Act"), 300.0), message="feed to follow the override")
    assert await read(client, "gAxis[0].Velocity") == pytest.approx(300.0)
    await write(client, "gFeed.Override", 150, U16)
    await wait_until(lambda: _eq(read(client, "gFeed.Act"), 900.0), message="feed to follow the override")

    await wait_until(lambda: _eq(read(client, "gProgram.Block"), 4), message="the next block")
    await wait_until(lambda: _eq(read(client, "gProgram.PartCount"), 1), timeout=20, message="M30")
    assert await read(client, "gMachine.State") == 0
    assert await read(client, "gProgram.Progress") == pytest.approx(100.0)
    assert (await read(client, "gAxis[0].ActPos"), await read(client, "gAxis[1].ActPos")) == (300.0, 100.0)
    assert await read(client, "gProgram.RunTime") > 0


async def _gt(value: Any, limit: float) -> bool:
    return (await value) > limit


async def _eq(value: Any, expected: float) -> bool:
    return (await value) == pytest.approx(expected)


async def test_writes_are_answered_like_a_controller(sim: Simulator, client: Client) -> None:
    assert await refused(client, "gAxis[0].ActPos", 1.0, D) == "BadNotWritable"
    assert await refused(client, "gMachine.State", 1, I16) == "BadNotWritable"
    assert await refused(client, "gFeed.Override", 500, U16) == "BadOutOfRange"
    assert await refused(client, "gFeed.Override", 50, I32) == "BadTypeMismatch"
    assert await refused(client, "gFeed.Override", 50.0, D) == "BadTypeMismatch"
    assert await refused(client, "gMachine.Mode", 3, I16) == "BadOutOfRange"
    assert await refused(client, "gCmd.Start", 1, I32) == "BadTypeMismatch"
    assert await refused(client, "gCmd.Start", True, B) == "BadInvalidState"  # nothing selected
    assert await refused(client, "gCmd.SelectProgram", "missing.nc", S) == "BadInvalidArgument"
    assert await refused(client, "gCmd.Pause", True, B) == "BadInvalidState"
    # the refusals changed nothing
    assert await read(client, "gFeed.Override") == 100
    assert await read(client, "gMachine.State") == 0

    await write(client, "gMachine.Mode", 1, I16)
    assert (await read(client, "gMachine.Mode"), await read(client, "gMachine.ModeText")) == (1, "Manual")
    await write(client, "gCmd.SelectProgram", "demo.nc", S)
    await write(client, "gCmd.Start", True, B)
    assert await refused(client, "gCmd.Start", True, B) == "BadInvalidState"  # already running
    assert await refused(client, "gCmd.SelectProgram", "demo.nc", S) == "BadInvalidState"
    await wait_until(lambda: _is(read(client, "gCmd.Start"), False), message="the Start bit to drop back")
    await write(client, "gCmd.Pause", True, B)
    assert await read(client, "gMachine.State") == 2
    await write(client, "gCmd.Stop", True, B)
    assert await read(client, "gMachine.State") == 0


async def _is(value: Any, expected: Any) -> bool:
    return (await value) is expected


async def test_soft_limit_alarm_and_reset(sim: Simulator, client: Client) -> None:
    await write(client, "gCmd.SelectProgram", "soft-limit.nc", S)
    await write(client, "gCmd.Start", True, B)
    await wait_until(lambda: _eq(read(client, "gMachine.State"), 3), message="the alarm")
    assert await read(client, "gAlarms.Count") == 1
    assert await read(client, "gAlarms.Ids") == [1001]
    assert await read(client, "gAlarms.Texts") == ["Soft limit X+ exceeded at line 7"]
    assert await read(client, "gAlarms.Severities") == [3]
    assert await read(client, "gMachine.StateText") == "Alarm"
    assert await read(client, "gAxis[0].ActPos") == pytest.approx(2900.0)
    await write(client, "gCmd.Reset", True, B)
    assert await read(client, "gMachine.State") == 0
    assert await read(client, "gAlarms.Count") == 0
    assert await read(client, "gAlarms.Ids") == []


async def test_browse_tree_types_and_access(sim: Simulator, client: Client) -> None:
    assert await client.get_namespace_index("urn:cnc-simulator:plc") == 2
    objects = client.nodes.objects
    act = await objects.get_child(["2:PLC", "2:Global", "2:gAxis", "2:gAxis[0]", "2:ActPos"])
    assert act.nodeid == ua.NodeId("::AsGlobalPV:gAxis[0].ActPos", 2)
    assert await act.read_data_type() == ua.NodeId(ua.ObjectIds.Double)
    assert await act.read_attribute(ua.AttributeIds.AccessLevel) is not None
    access = (await act.read_attribute(ua.AttributeIds.AccessLevel)).Value.Value
    assert access & ua.AccessLevel.CurrentWrite.mask == 0
    override = await objects.get_child(["2:PLC", "2:Global", "2:gFeed", "2:Override"])
    assert (
        await override.read_attribute(ua.AttributeIds.AccessLevel)
    ).Value.Value & ua.AccessLevel.CurrentWrite.mask
    assert await override.read_data_type() == ua.NodeId(ua.ObjectIds.UInt16)
    table = await objects.get_child(["2:PLC", "2:Tasks", "2:Laser", "2:powerTable"])
    assert table.nodeid == ua.NodeId("::Laser:powerTable", 2)
    assert await table.read_value_rank() == 1
    assert await table.read_array_dimensions() == [5]
    assert await table.read_value() == [20.0, 40.0, 60.0, 80.0, 100.0]
    head = await objects.get_child(["2:PLC", "2:Tasks", "2:Laser", "2:headTemp"])
    assert await head.read_data_type() == ua.NodeId(ua.ObjectIds.Float)
    axes = await (await objects.get_child(["2:PLC", "2:Global", "2:gAxis"])).get_children()
    assert [(await n.read_browse_name()).Name for n in axes] == ["gAxis[0]", "gAxis[1]", "gAxis[2]"]
    ignore = client.get_node("ns=2;s=::AsGlobalPV:gSim.IgnoreStart")
    await ignore.write_value(ua.Variant(True, B))
    await write(client, "gCmd.SelectProgram", "demo.nc", S)
    await write(client, "gCmd.Start", True, B)  # accepted ...
    assert await read(client, "gMachine.State") == 0  # ... and ignored


async def test_values_carry_the_machine_clock_and_change_only_when_changed(tmp_path: Any) -> None:
    def plc_clock() -> datetime:  # a controller whose clock is an hour behind
        return datetime.now(UTC) - timedelta(hours=1)

    async with (
        Simulator(
            opcua_port=free_port(), ftp_port=free_port(), speed=10, store=tmp_path, clock=plc_clock
        ) as sim,
        Client(sim.opcua_endpoint, timeout=5) as client,
    ):
        referenced = client.get_node(G + "gAxis[0].Referenced")
        first = await referenced.read_data_value()
        assert first.SourceTimestamp is not None
        assert first.SourceTimestamp < datetime.now(UTC) - timedelta(minutes=59)
        await write(client, "gCmd.SelectProgram", "demo.nc", S)
        await write(client, "gCmd.Start", True, B)
        x = client.get_node(G + "gAxis[0].ActPos")
        before = await x.read_data_value()
        await wait_until(lambda: _later(x, before.SourceTimestamp), message="X to be written again")
        now = await x.read_data_value()
        assert now.SourceTimestamp < datetime.now(UTC) - timedelta(minutes=59) < now.ServerTimestamp
        assert (await referenced.read_data_value()).SourceTimestamp == first.SourceTimestamp


async def _later(node: Any, than: Any) -> bool:
    return (await node.read_data_value()).SourceTimestamp > than


async def test_loop_program_restarts_after_each_end(tmp_path: Any) -> None:
    async with Simulator(
        opcua_port=free_port(), ftp_port=free_port(), speed=200.0, store=tmp_path, loop_program="demo.nc"
    ) as sim:
        assert sim.machine.state == 1
        await wait_until(lambda: sim.machine.program.part_count >= 2, timeout=15, message="two loops")


async def test_user_and_password_when_configured(tmp_path: Any) -> None:
    async with Simulator(
        opcua_port=free_port(), ftp_port=free_port(), store=tmp_path, opcua_user="op", opcua_password="pw"
    ) as sim:
        with pytest.raises(UaStatusCodeError):
            async with Client(sim.opcua_endpoint, timeout=5):
                pass
        client = Client(sim.opcua_endpoint, timeout=5)
        client.set_user("op")
        client.set_password("pw")
        async with client:
            assert await read(client, "gMachine.StateText") == "Idle"
