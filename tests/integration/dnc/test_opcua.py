"""A drip-feed seen and steered through the OPC UA server: Jobs/Block, LeadSeconds, Held, and the
Commands/Drip* methods called by a real asyncua client."""

from __future__ import annotations

import asyncio
from pathlib import Path
from typing import Any

from asyncua import ua
from asyncua.ua.uaerrors import UaStatusCodeError

from gateway.config.gateway import GatewayConfig
from gateway.config.jobs import InboxConfig
from gateway.config.loader import Config, load_mapping
from gateway.jobs.queue.store import JobState
from gateway.jobs.service import JobService
from gateway.model.tree import VariableTree
from gateway.sinks.opcua.config import OpcUaServerConfig
from gateway.sinks.opcua.server import OpcUaSink
from tests.integration.dnc.rig import Mode, drip_program, face, simulator
from tests.integration.dnc.test_jobs import serial_mapping
from tests.opcua_client import Client
from tests.waiting import free_port, wait_until


async def read(client: Client, path: str) -> Any:
    return await client.get_node(f"ns=2;s=lathe/{path}").read_value()


async def test_drip_progress_and_commands_over_opc_ua(tmp_path: Path) -> None:
    async with simulator(tmp_path, mode=Mode.DRIP) as sim:
        path = tmp_path / "lathe.yaml"
        path.write_text(serial_mapping(face(sim).socket_url or ""))
        state = tmp_path / "state"
        gateway = GatewayConfig(
            opcua=OpcUaServerConfig(endpoint=f"opc.tcp://127.0.0.1:{free_port()}/cnc-gateway"),
            state_dir=str(state),
            inbox=InboxConfig(enabled=False),
        )
        config = Config(gateway, (load_mapping(path, environ={}),), tmp_path)
        tree = VariableTree(config.definitions())
        service = JobService(config, tree)
        sink = OpcUaSink(tree, config.gateway.opcua, state)
        async with sink, service:
            tasks = [asyncio.create_task(sink.run()), asyncio.create_task(service.run())]
            try:
                async with Client(sink.endpoint) as client:
                    commands = client.get_node("ns=2;s=lathe/Commands")
                    reply = await service.submit_bytes(
                        "lathe", "part.nc", drip_program(400), user="alice", origin="test"
                    )
                    assert reply.ok
                    seq = int(reply.job_id[1:]) if reply.job_id else 1
                    await wait_until(lambda: read(client, "Jobs/Block"), timeout=30, message="Jobs/Block > 0")
                    assert await read(client, "Jobs/RemainingSeconds") > 0
                    await commands.call_method("2:DripPause")
                    await wait_until(
                        lambda: _equals(read(client, "Jobs/Held"), "paused"), message="Jobs/Held paused"
                    )
                    await commands.call_method("2:DripResume")
                    await wait_until(
                        lambda: service.queue.get(seq).state is JobState.DELIVERED, timeout=60, message="done"
                    )
                    try:
                        await commands.call_method(
                            "2:DripRestart", ua.Variant("J000001", ua.VariantType.String),
                            ua.Variant(5, ua.VariantType.UInt32),
                        )  # fmt: skip
                        status = "Good"
                    except UaStatusCodeError as exc:
                        status = ua.StatusCode(exc.code).name
                    assert status == "BadInvalidState"  # DELIVERED: only a FAILED job restarts
            finally:
                for task in tasks:
                    task.cancel()
                await asyncio.gather(*tasks, return_exceptions=True)


async def _equals(value: Any, expected: Any) -> bool:
    return bool(await value == expected)
