"""`shard: lease` seen by an OPC UA client: the shards of a fleet as a non-transparent redundant server set.

Two shards of `cnc-gateway fleet` over a simulator fleet of two, leases in PostgreSQL. Read with asyncua's
client, as a SCADA with redundant connections reads (OPC UA Part 4, 6.6.2): each server says Warm
redundancy, lists both servers' application URIs in ServerUriArray, and carries a ServiceLevel; each shows
both machines, a machine Good with its folder's ServiceLevel 255 on the shard that holds its lease, Bad
(BadOutOfService) with 1 on the other. A shard killed: the survivor serves both, at ServiceLevel 255.
And the database: a cut shorter than the lease does not interrupt serving; a longer one stops it, until
the database is back.
"""

from __future__ import annotations

import asyncio
import contextlib
import os
import re
import signal
import socket
import time
import urllib.request
from pathlib import Path
from urllib.parse import urlsplit

import psycopg
from asyncua import ua

from simulator.fleet import SimulatorFleet
from tests.fleet_rig import Fleet, write_fleet
from tests.opcua_client import Client
from tests.postgres import ADMIN_URL
from tests.waiting import free_port, wait_until


def listening(port: int) -> bool:
    try:
        socket.create_connection(("127.0.0.1", port), timeout=1).close()
    except OSError:
        return False
    return True


async def quietly_disconnect(client: Client) -> None:
    with contextlib.suppress(Exception):  # its server may have been killed under it: nothing to close
        await client.disconnect()


async def read(client: Client, node_id: str | int) -> ua.DataValue:
    node = client.get_node(ua.NodeId(node_id, 0) if isinstance(node_id, int) else node_id)
    return await node.read_data_value(raise_on_bad_status=False)


async def machine_view(client: Client, machine: str) -> tuple[int, bool, str]:
    """(the machine folder's ServiceLevel, Status/Served, the status code of one of its values)."""
    level = await read(client, f"ns=2;s={machine}/Status/ServiceLevel")
    served = await read(client, f"ns=2;s={machine}/Status/Served")
    value = await read(client, f"ns=2;s={machine}/Axes/X/Position")
    assert value.StatusCode is not None
    return int(level.Value.Value), bool(served.Value.Value), value.StatusCode.name


async def test_shards_form_a_redundant_set_with_a_service_level_per_machine(
    tmp_path: Path, postgres_url: str
) -> None:
    http, opcua, inbox = free_port(), free_port(), free_port()
    async with SimulatorFleet(2, store_root=tmp_path / "stores", tick=0.1) as sims:
        names = [p.name for p in sims.write_mappings(tmp_path)]
        ports = {"HTTP_PORT": http, "OPCUA_PORT": opcua, "INBOX_PORT": inbox}
        fleet_file = write_fleet(tmp_path, names, ports, shard="lease", restart="{initial: 60, max: 60}",
                                 gateway=f"queue: {postgres_url}\nlease_time: 2\n")  # fmt: skip
        async with Fleet(fleet_file) as fleet:
            await wait_until(lambda: fleet.said("every shard started"), timeout=60, message="both shards up")
            for port in (opcua, opcua + 1):
                try:
                    await wait_until(lambda: listening(port), timeout=20, message=f"OPC UA on {port}")  # noqa: B023
                except AssertionError:
                    print("".join(fleet.err)[-5000:])
                    raise
            one = Client(f"opc.tcp://127.0.0.1:{opcua}/cnc-gateway")
            two = Client(f"opc.tcp://127.0.0.1:{opcua + 1}/cnc-gateway")
            async with one, contextlib.AsyncExitStack() as stack:
                await two.connect()
                stack.push_async_callback(quietly_disconnect, two)

                async def views() -> dict[str, tuple[tuple[int, bool, str], tuple[int, bool, str]]]:
                    return {m: (await machine_view(one, m), await machine_view(two, m))
                            for m in ("laser-001", "laser-002")}  # fmt: skip

                async def shared_out() -> bool:
                    seen = await views()
                    return all(
                        sorted([a, b]) == [(1, False, "BadOutOfService"), (255, True, "Good")]
                        for a, b in seen.values()
                    ) and {a[0] for a, _ in seen.values()} == {1, 255}

                await wait_until(shared_out, timeout=60, interval=0.2, message="one machine Good on each")
                for client in (one, two):
                    support = await read(client, ua.ObjectIds.Server_ServerRedundancy_RedundancySupport)
                    assert support.Value.Value == ua.RedundancySupport.Warm
                    uris = await read(client, ua.ObjectIds.Server_ServerRedundancy_ServerUriArray)
                    assert len(uris.Value.Value) == 2 and all(":shard-" in u for u in uris.Value.Value)
                    mine = await read(client, ua.ObjectIds.Server_ServerArray)
                    assert mine.Value.Value[0] in uris.Value.Value  # its own application URI is in the set

                    async def at_227(client: Client = client) -> bool:
                        return bool((await read(client, ua.ObjectIds.Server_ServiceLevel)).Value.Value == 227)

                    # 200 + 55 × 1 of 2 machines (it follows the machines served within half a second)
                    await wait_until(at_227, timeout=10, message="ServiceLevel 227")
                os.kill(fleet.starts(2)[-1], signal.SIGKILL)

                async def survivor_serves_both() -> bool:
                    level = await read(one, ua.ObjectIds.Server_ServiceLevel)
                    views = [await machine_view(one, m) for m in ("laser-001", "laser-002")]
                    return level.Value.Value == 255 and views == [(255, True, "Good")] * 2

                await wait_until(
                    survivor_serves_both, timeout=30, interval=0.2, message="shard 1 serving both"
                )
            fleet.proc.send_signal(signal.SIGTERM)
            assert await asyncio.wait_for(fleet.proc.wait(), 30) == 0
    log = "".join(fleet.err)
    assert "Traceback" not in log, log[-3000:]


def serving(port: int) -> set[str]:
    """The machines a shard serves and is connected to, from its /metrics (empty while it cannot answer)."""
    try:
        with urllib.request.urlopen(f"http://127.0.0.1:{port}/metrics", timeout=2) as answer:
            text = answer.read().decode()
    except OSError:
        return set()
    return set(re.findall(r'cnc_gateway_machine_connected\{machine="([^"]+)"\} 1\.0', text))


def set_reachable(database: str, reachable: bool) -> None:
    """The database cut as a restart or a network cut looks from the gateway: sessions ended, new refused."""
    with psycopg.connect(ADMIN_URL, autocommit=True, connect_timeout=5) as admin:
        admin.execute(f'ALTER DATABASE "{database}" ALLOW_CONNECTIONS {str(reachable).lower()}'.encode())
        if not reachable:
            admin.execute(
                "SELECT pg_terminate_backend(pid) FROM pg_stat_activity WHERE datname = %s", (database,)
            )


async def test_a_database_cut_shorter_than_the_lease_keeps_serving_a_longer_one_stops_it(
    tmp_path: Path, postgres_url: str
) -> None:
    """Issue 29: shards keep mirroring through a database restart; a shard that cannot renew stops serving
    once its lease may have run out (no machine served by anyone meanwhile: nobody can take it), and serves
    again when the database is back."""
    lease = 6.0
    http, opcua, inbox = free_port(), free_port(), free_port()
    machines = {"laser-001", "laser-002"}
    database = urlsplit(postgres_url).path.lstrip("/")
    async with SimulatorFleet(2, store_root=tmp_path / "stores", tick=0.1) as sims:
        names = [p.name for p in sims.write_mappings(tmp_path)]
        ports = {"HTTP_PORT": http, "OPCUA_PORT": opcua, "INBOX_PORT": inbox}
        fleet_file = write_fleet(tmp_path, names, ports, shard="lease",
                                 gateway=f"queue: {postgres_url}\nlease_time: {lease}\n")  # fmt: skip

        def served() -> set[str]:
            return serving(http) | serving(http + 1)

        async with Fleet(fleet_file) as fleet:
            await wait_until(lambda: served() == machines and serving(http) and serving(http + 1),
                             timeout=60, interval=0.2, message="one machine on each shard")  # fmt: skip
            seen: list[set[str]] = []
            try:
                set_reachable(database, False)  # a restart's length: 2 s
                deadline = time.monotonic() + 2.0
                while time.monotonic() < deadline:
                    seen.append(await asyncio.to_thread(served))
                    await asyncio.sleep(0.1)
                set_reachable(database, True)
                assert seen and all(s == machines for s in seen), (
                    f"during a 2-s cut: {seen}; {fleet.err[-9:]}"
                )

                set_reachable(database, False)  # longer than the lease: nobody may serve
                await wait_until(lambda: served() == set(), timeout=lease + 5, interval=0.1,
                                 message="both shards stopped serving without the database")  # fmt: skip
            finally:
                set_reachable(database, True)
            await wait_until(lambda: served() == machines, timeout=60, interval=0.2,
                             message="every machine served again once the database is back")  # fmt: skip
            fleet.proc.send_signal(signal.SIGTERM)
            assert await asyncio.wait_for(fleet.proc.wait(), 30) == 0
    log = "".join(fleet.err)
    assert "Traceback" not in log, log[-3000:]
    assert "cannot reach the lease table" in log
