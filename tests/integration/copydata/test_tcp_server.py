"""tcp-server lifecycle: a port that is taken does not stop the gateway; shutdown with clients is quiet."""

from __future__ import annotations

import asyncio
import logging
import socket

import pytest

from gateway.sinks.copydata.sink import CopydataSink
from gateway.sinks.copydata.tcp import TcpServerTransport
from tests.trees import MappedTree
from tests.unit.sinks.copydata.helpers import mapping
from tests.waiting import free_port, wait_until


async def test_the_target_waits_for_its_port_and_reports_why(caplog: pytest.LogCaptureFixture) -> None:
    caplog.set_level(logging.INFO, logger="gateway.sinks.copydata")
    port = free_port()
    squatter = socket.socket()
    squatter.bind(("127.0.0.1", port))
    squatter.listen()
    tree = MappedTree([mapping({"name": "nest", "transport": "tcp-server", "bind": "127.0.0.1", "port": port,
                                "backoff": {"initial": 0.05, "max": 0.1}})])  # fmt: skip
    sink = CopydataSink(tree, tree.mappings)
    status = tree.machines["m1"].nodes["Status/CopydataTargets"]
    async with sink:
        task = asyncio.create_task(sink.run())
        try:
            await wait_until(lambda: "not listening (address already in use)" in status.sample.value,
                             message="the status to say why")  # fmt: skip
            errors = [r for r in caplog.records if r.levelno == logging.ERROR]
            assert len(errors) == 1 and f"cannot listen on 127.0.0.1:{port}" in errors[0].getMessage()
            squatter.close()
            transport = sink.emitters[0].transport
            assert isinstance(transport, TcpServerTransport)
            await asyncio.wait_for(transport.listening.wait(), 10)
            assert status.sample.value == f"nest: tcp-server 127.0.0.1:{port} listening, 0 clients"
            _, writer = await asyncio.open_connection("127.0.0.1", port)
            writer.close()
            assert not task.done()
        finally:
            squatter.close()
            task.cancel()
            await asyncio.gather(task, return_exceptions=True)


async def test_stopping_with_clients_connected_is_quiet(caplog: pytest.LogCaptureFixture) -> None:
    """Shutdown cancels the client handlers; asyncio must not log a traceback for any of them."""
    caplog.set_level(logging.INFO)
    tree = MappedTree([mapping({"name": "nest", "transport": "tcp-server", "bind": "127.0.0.1", "port": 0})])
    sink = CopydataSink(tree, tree.mappings)
    clients = []
    async with sink:
        task = asyncio.create_task(sink.run())
        transport = sink.emitters[0].transport
        assert isinstance(transport, TcpServerTransport)
        await asyncio.wait_for(transport.listening.wait(), 10)
        for _ in range(3):
            clients.append(await asyncio.open_connection("127.0.0.1", transport.port))
        await wait_until(lambda: sink.emitters[0].stats()["receivers"] == 3, message="three clients")
        task.cancel()
        await asyncio.gather(task, return_exceptions=True)
    for _ in range(5):
        await asyncio.sleep(0)  # let asyncio run the handlers' done-callbacks
    for reader, writer in clients:
        assert await reader.read() == b""  # closed by the gateway
        writer.close()
    noisy = [r for r in caplog.records if r.levelno >= logging.ERROR or "Traceback" in r.getMessage()]
    assert not noisy, [r.getMessage() for r in noisy]
