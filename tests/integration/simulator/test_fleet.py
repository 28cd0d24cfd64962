"""`cnc-simulator --machines N`: a fleet of laser cutters from one process, each its own OPC UA and FTP.

The mapping files it writes are what a gateway loads: they pass the gateway's loader, their node ids
are read from each machine's own server, and a static shard (`shard: K/N`) takes its part of them
(tests/integration/jobs/test_postgres_flow.py delivers a job to one machine of a fleet).
"""

from __future__ import annotations

import asyncio
import signal
from pathlib import Path

from asyncua import Client

from gateway.config.loader import load, load_mapping
from simulator.fleet import SimulatorFleet, machine_name
from tests.integration.simulator.test_cli import command
from tests.waiting import wait_until


async def test_each_machine_runs_on_its_own_servers_and_the_mappings_fit_them(tmp_path: Path) -> None:
    async with SimulatorFleet(3, store_root=tmp_path / "stores", loop_program="demo.nc", speed=5) as fleet:
        paths = fleet.write_mappings(tmp_path / "mappings")
        assert [p.name for p in paths] == ["laser-001.yaml", "laser-002.yaml", "laser-003.yaml"]
        endpoints = {sim.opcua_endpoint for sim in fleet.machines}
        assert len(endpoints) == 3 and len({sim.ftp_port for sim in fleet.machines}) == 3
        for index, path in enumerate(paths, start=1):
            mapping = load_mapping(path, environ={})
            assert mapping.machine == machine_name(index)
            sim = fleet.machines[index - 1]
            async with Client(sim.opcua_endpoint, timeout=5) as client:  # each variable's node is there
                for spec in mapping.variables:
                    await client.get_node(spec.source).read_value()

                async def running(client: Client = client) -> bool:
                    state = await client.get_node("ns=2;s=::AsGlobalPV:gMachine.StateText").read_value()
                    return bool(state == "Running")

                await wait_until(running, timeout=20, message=f"{mapping.machine} running demo.nc")
            assert (tmp_path / "stores" / machine_name(index) / "DATA" / "Programs" / "demo.nc").is_file()
        gateway = tmp_path / "mappings" / "gateway.yaml"
        names = [p.name for p in paths]
        shards = []
        for k in (1, 2):
            gateway.write_text(f"machines: {names}\nshard: {k}/2\n")
            shards.append(sorted(m.machine for m in load([gateway], environ={}).machines))
        assert shards == [["laser-001", "laser-003"], ["laser-002"]]


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
            state = await client.get_node("ns=2;s=::AsGlobalPV:gMachine.StateText").read_value()
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
