"""MTConnect over real sockets: the agent sink on a free port, an HTTP client, a reader of streamed parts."""

from __future__ import annotations

from collections.abc import AsyncIterator
from contextlib import asynccontextmanager
from pathlib import Path
from typing import Any

import aiohttp

from gateway.codecs.mtconnect.multipart import MultipartReader, boundary_of
from gateway.config.loader import Config
from gateway.model.tree import VariableTree
from gateway.sinks.mtconnect.sink import MTConnectSink
from tests.mtconnect_shop import shop
from tests.unit.codecs.mtconnect.conftest import assert_valid, schemas

__all__ = ["Http", "agent_sink", "assert_valid", "fed", "schemas", "shop"]


class Http:
    """GETs against one agent; answers as (status, content type, text)."""

    def __init__(self, session: aiohttp.ClientSession, url: str) -> None:
        self.session = session
        self.url = url

    async def get(self, target: str, **headers: str) -> tuple[int, str, str]:
        async with self.session.get(self.url + target, headers=headers) as response:
            return response.status, response.headers.get("Content-Type", ""), await response.text()

    @asynccontextmanager
    async def stream(self, target: str) -> AsyncIterator[AsyncIterator[str]]:
        """The parts of a streamed answer, as an async iterator of documents."""
        async with self.session.get(self.url + target) as response:
            assert response.status == 200, await response.text()
            boundary = boundary_of(response.headers["Content-Type"])
            assert boundary is not None, response.headers["Content-Type"]
            reader = MultipartReader(boundary)

            async def parts() -> AsyncIterator[str]:
                async for data in response.content.iter_any():
                    for part in reader.feed(data):
                        yield part.decode("utf-8")
                    assert reader.failed is None, reader.failed

            yield parts()


@asynccontextmanager
async def agent_sink(config: Config) -> AsyncIterator[tuple[VariableTree, MTConnectSink, Http]]:
    """The gateway's agent face for `config`'s machines, alone (no controller, no OPC UA), serving and fed."""
    import asyncio

    tree = VariableTree(config.definitions())
    assert config.gateway.mtconnect is not None
    sink = MTConnectSink(tree, config.gateway.mtconnect, config.mappings, config.state_dir)
    async with sink, aiohttp.ClientSession() as session:
        task = asyncio.create_task(sink.run(), name="sink:mtconnect")
        try:
            yield tree, sink, Http(session, sink.url)
        finally:
            task.cancel()
            await asyncio.gather(task, return_exceptions=True)


async def fed(sink: MTConnectSink) -> None:
    """Until the sink's feed has taken every change the tree published so far."""
    import asyncio

    from tests.waiting import wait_until

    changes = sink._changes
    assert changes is not None
    await wait_until(lambda: not changes.backlog, message="the agent's feed")
    await asyncio.sleep(0)


def state_config(tmp_path: Path, **kwargs: Any) -> Config:
    return shop(state_dir=tmp_path / "state", **kwargs)
