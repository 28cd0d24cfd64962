"""`cnc-simulator --machines N`: a fleet of laser cutters from one process, one OPC UA server, FTP each.

The mapping files it writes are what a gateway loads: they pass the gateway's loader, their node ids
are read from each machine's folder of the one server, writes reach the machine that owns the node and
no other, and a static shard (`shard: K/N`) takes its part of them
(tests/integration/jobs/test_postgres_flow.py delivers a job to one machine of a fleet).
"""

from __future__ import annotations

import asyncio
import signal
from pathlib import Path

from asyncua import ua
from asyncua.ua.uaerrors import UaStatusCodeError

from gateway.config.loader import load, load_mapping
from simulator.fleet import SimulatorFleet, machine_name
from tests.integration.simulator.test_cli import command
from tests.opcua_client import Client
from tests.waiting import wait_until


async def test_each_machine_runs_in_its_own_folder_and_the_mappings_fit_them(tmp_path: Path) -> None:
    async with SimulatorFleet(3, store_root=tmp_path / "stores", loop_program="demo.nc", speed=5) as fleet:
        paths = fleet.write_mappings(tmp_path / "mappings")
        assert [p.name for p in paths] == ["laser-001.yaml", "laser-002.yaml", "laser-003.yaml"]
        endpoints = {sim.opcua_endpoint for sim in fleet.machines}
        assert endpoints == {fleet.opcua.endpoint} and len({sim.ftp_port for sim in fleet.machines}) == 3
        for index, path in enumerate(paths, start=1):
            mapping = load_mapping(path, environ={})
            assert mapping.machine == machine_name(index)
            sim = fleet.machines[index - 1]
            async with Client(sim.opcua_endpoint, timeout=5) as client:  # each variable's node is there
                for spec in mapping.variables:
                    await client.get_node(spec.source).read_value()

                async def running(client: Client = client, name: str = mapping.machine) -> bool:
                    node = client.get_node(f"ns=2;s={name}/::AsGlobalPV:gMachine.StateText")
                    return bool(await node.read_value() == "Running")

                await wait_until(running, timeout=20, message=f"{mapping.machine} running demo.nc")
            assert (tmp_path / "stores" / machine_name(index) / "DATA" / "Programs" / "demo.nc").is_file()
        gateway = tmp_path / "mappings" / "gateway.yaml"
        names = [p.name for p in paths]
        shards = []
        for k in (1, 2):
            gateway.write_text(f"machines: {names}\nshard: {k}/2\n")
            shards.append(sorted(m.machine for m in load([gateway], environ={}).machines))
        assert shards == [["laser-001", "laser-003"], ["laser-002"]]
        # Reached by another name (a compose service): the mappings say it, the ports stay the same.
        elsewhere = load_mapping(fleet.write_mappings(tmp_path / "compose", "simulator")[1], environ={})
        assert elsewhere.driver.endpoint == f"opc.tcp://simulator:{fleet.machines[1].opcua_port}"
        assert elsewhere.jobs is not None and elsewhere.jobs.controller.host == "simulator"
        assert elsewhere.jobs.controller.port == fleet.machines[1].ftp_port


async def test_the_command_serves_a_fleet_writes_its_mappings_and_stops_on_a_signal(tmp_path: Path) -> None:
    proc = await asyncio.create_subprocess_exec(
        *command(),
        *("--machines", "3", "--opcua-port", "0", "--ftp-port", "0"),
        *("--store", str(tmp_path / "stores"), "--fleet-mappings", str(tmp_path / "mappings")),
        stdout=asyncio.subprocess.PIPE,
        stderr=asyncio.subprocess.PIPE,
    )
    try:
        await wait_until(
            lambda: len(list((tmp_path / "mappings").glob("laser-*.yaml"))) == 3,
            timeout=30,
            message="the fleet's mappings",
        )
        mapping = load_mapping(tmp_path / "mappings" / "laser-003.yaml", environ={})
        async with Client(mapping.driver.endpoint, timeout=5) as client:
            state = await client.get_node("ns=2;s=laser-003/::AsGlobalPV:gMachine.StateText").read_value()
        assert state == "Idle"
        proc.send_signal(signal.SIGTERM)
        out, err = await asyncio.wait_for(proc.communicate(), 20)
    finally:
        if proc.returncode is None:
            proc.kill()
            await proc.wait()
    assert proc.returncode == 0, err.decode()
    assert "Traceback" not in err.decode()
    assert "a fleet of 3 laser cutters" in out.decode() and "laser-003  opc.tcp://127.0.0.1:" in out.decode()
    assert "(laser-003/)" in out.decode()


async def test_a_write_reaches_the_machine_that_owns_the_node_and_no_other(tmp_path: Path) -> None:
    async with (
        SimulatorFleet(3, store_root=tmp_path / "stores") as fleet,
        Client(fleet.opcua.endpoint) as client,
    ):
        node = client.get_node("ns=2;s=laser-002/::AsGlobalPV:gFeed.Override")
        await node.write_value(ua.DataValue(ua.Variant(77, ua.VariantType.UInt16)))
        assert [sim.machine.override for sim in fleet.machines] == [100, 77, 100]
        assert await node.read_value() == 77
        # A controller's answers, as from a machine's own server: the wrong type, a folder, no such node.
        refusals = [
            ("ns=2;s=laser-001/::AsGlobalPV:gFeed.Override", ua.Variant(5.0, ua.VariantType.Double)),
            ("ns=2;s=laser-001", ua.Variant(1, ua.VariantType.UInt16)),
            ("ns=2;s=laser-009/::AsGlobalPV:gFeed.Override", ua.Variant(1, ua.VariantType.UInt16)),
        ]
        codes = []
        for node_id, variant in refusals:
            try:
                await client.get_node(node_id).write_value(ua.DataValue(variant))
            except UaStatusCodeError as exc:
                codes.append(exc.code)
        assert codes == [ua.StatusCodes.BadTypeMismatch, ua.StatusCodes.BadNotWritable,
                         ua.StatusCodes.BadNodeIdUnknown]  # fmt: skip
        assert [sim.machine.override for sim in fleet.machines] == [100, 77, 100]
