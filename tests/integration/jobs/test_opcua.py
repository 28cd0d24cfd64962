"""The job queue through the OPC UA server: the machine's Jobs object, and Programs methods called
by a real asyncua client, against the simulator's real FTP program store."""

from __future__ import annotations

from collections.abc import AsyncIterator
from dataclasses import dataclass
from pathlib import Path

import pytest
from asyncua import Node, ua
from asyncua.ua.uaerrors import UaStatusCodeError

from gateway.config.gateway import GatewayConfig
from gateway.config.jobs import InboxConfig
from gateway.config.loader import Config, load_mapping
from gateway.jobs.queue.store import JobState
from gateway.jobs.service import JobService
from gateway.model.tree import VariableTree
from gateway.sinks.opcua.config import OpcUaServerConfig
from gateway.sinks.opcua.server import OpcUaSink
from tests.integration.jobs.conftest import GOOD, Store, mapping_text
from tests.opcua_client import Client
from tests.waiting import free_port, wait_until


@dataclass
class Env:
    client: Client
    service: JobService
    store: Store
    state: Path

    def programs(self, machine: str = "laser") -> Node:
        return self.client.get_node(f"ns=2;s={machine}/Programs")

    async def call(self, name: str, *args: object, machine: str = "laser") -> object:
        return await self.programs(machine).call_method(f"2:{name}", *args)

    async def status_of(self, name: str, *args: object, machine: str = "laser") -> str:
        try:
            await self.call(name, *args, machine=machine)
        except UaStatusCodeError as exc:
            return ua.StatusCode(exc.code).name
        return "Good"


@pytest.fixture
async def env(store: Store, tmp_path: Path) -> AsyncIterator[Env]:
    files = []
    for name, port in (("laser", store.port), ("press", free_port())):  # press: a controller that is down
        path = tmp_path / f"{name}.yaml"
        path.write_text(mapping_text(name, port))
        files.append(load_mapping(path, environ={}))
    state = tmp_path / "state"
    gateway = GatewayConfig(
        opcua=OpcUaServerConfig(endpoint=f"opc.tcp://127.0.0.1:{free_port()}/cnc-gateway"),
        state_dir=str(state),
        inbox=InboxConfig(enabled=False),
    )
    config = Config(gateway, tuple(files), tmp_path)
    tree = VariableTree(config.definitions())
    service = JobService(config, tree)  # before the sink starts: it adds Jobs/ and Programs
    sink = OpcUaSink(tree, config.gateway.opcua, state)
    async with sink, service:
        import asyncio

        tasks = [asyncio.create_task(sink.run()), asyncio.create_task(service.run())]
        try:
            async with Client(sink.endpoint) as client:
                yield Env(client, service, store, state)
        finally:
            for task in tasks:
                task.cancel()
            await asyncio.gather(*tasks, return_exceptions=True)


async def test_programs_methods_list_get_backup_and_delete(env: Env) -> None:
    names, sizes = await env.call("List")
    files = env.store.files()
    assert names == sorted(files) and sizes == [len(files[n]) for n in names]
    assert await env.call("Get", "demo.nc") == files["demo.nc"].decode()
    name = str(await env.call("Backup", "demo.nc"))  # the copy's name: never the server's path
    assert "/" not in name and name.endswith("-demo.nc")
    assert (env.state / "backups" / "laser" / name).read_bytes() == files["demo.nc"]
    assert await env.call("Delete", "soft-limit.nc") is None  # no outputs
    assert "soft-limit.nc" not in env.store.files()


async def test_put_goes_through_validation_and_the_queue(env: Env) -> None:
    job_id, message = await env.call("Put", "opc.nc", GOOD.decode())
    assert job_id == "J000001" and message.startswith("J000001 queued for laser")
    queue = env.service.queue
    await wait_until(lambda: queue.get(1).state is JobState.DELIVERED, message="the Put job delivered")
    assert env.store.files()["opc.nc"] == GOOD
    assert queue.get(1).origin == "opcua"
    last = env.client.get_node("ns=2;s=laser/Jobs/LastDelivered")
    await wait_until(last.read_value, message="Jobs/LastDelivered over OPC UA")
    assert await last.read_value() == "J000001 opc.nc"
    job_id, message = await env.call("Put", "bad.nc", "G1 X1 F100\n")
    assert job_id == "J000002" and "rejected" in message and "end code" in message
    assert queue.get(2).state is JobState.REJECTED


async def test_the_jobs_object_shows_the_queue(env: Env) -> None:
    jobs = env.client.get_node("ns=2;s=laser/Jobs")
    assert (await jobs.read_node_class()) == ua.NodeClass.Object
    names = {(await child.read_browse_name()).Name for child in await jobs.get_children()}
    assert {"QueueLength", "Current", "LastDelivered", "LastFailed", "LastFailedReason", "Progress"} <= names
    assert await env.client.get_node("ns=2;s=laser/Jobs/QueueLength").read_value() == 0


WRONG_CALLS = [
    ("List", ("extra",), "BadTooManyArguments"),
    ("Get", (), "BadArgumentsMissing"),
    ("Get", (ua.Variant(5, ua.VariantType.Int32),), "BadTypeMismatch"),
    ("Get", ("../etc/passwd",), "BadInvalidArgument"),
    ("Put", ("x.nc", ua.Variant([1.0], ua.VariantType.Double, is_array=True)), "BadTypeMismatch"),
    ("Get", ("missing.nc",), "BadNotFound"),
    ("Delete", ("missing.nc",), "BadNotFound"),
]


async def test_wrong_calls_get_the_matching_status(env: Env) -> None:
    got = [(method, await env.status_of(method, *args)) for method, args, _ in WRONG_CALLS]
    assert got == [(method, status) for method, _, status in WRONG_CALLS]
    assert env.service.queue.count() == 0


async def test_a_controller_that_is_down_is_bad_not_connected(env: Env) -> None:
    assert await env.status_of("List", machine="press") == "BadNotConnected"


async def test_methods_declare_their_arguments(env: Env) -> None:
    get = env.client.get_node("ns=2;s=laser/Programs/Get")
    assert await get.read_node_class() == ua.NodeClass.Method
    inputs = await env.client.get_node("ns=2;s=laser/Programs/Get/InputArguments").read_value()
    outputs = await env.client.get_node("ns=2;s=laser/Programs/Get/OutputArguments").read_value()
    assert [(a.Name, a.DataType) for a in inputs] == [("Name", ua.NodeId(ua.ObjectIds.String, 0))]
    assert [a.Name for a in outputs] == ["Content"]
