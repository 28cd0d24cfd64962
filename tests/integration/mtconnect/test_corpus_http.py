"""tests/corpus/mtconnect/requests.yaml over a real HTTP connection: each bad request gets its MTConnectError.

The request line goes out byte for byte on a raw socket (an HTTP client library would
re-quote `%ff` and friends), to the agent's own server. Every case must be answered
with the corpus' error code, in a document that validates, and the agent must go on
answering: a good request after each bad one.
"""

from __future__ import annotations

import asyncio
from collections.abc import AsyncIterator
from typing import Any

import pytest

from gateway.codecs.mtconnect.errors import HTTP_STATUS, ErrorCode
from gateway.sinks.mtconnect.agent import Agent
from gateway.sinks.mtconnect.config import AgentConfig
from gateway.sinks.mtconnect.http import AgentServer
from gateway.sinks.mtconnect.profile import Profile
from tests.integration.mtconnect.conftest import assert_valid, schemas  # noqa: F401
from tests.unit.codecs.mtconnect.machines import shop
from tests.unit.codecs.mtconnect.test_corpus import cases


async def raw_get(port: int, target: str) -> tuple[int, str]:
    reader, writer = await asyncio.open_connection("127.0.0.1", port)
    writer.write(f"GET {target} HTTP/1.1\r\nHost: agent\r\nConnection: close\r\n\r\n".encode("latin-1"))
    await writer.drain()
    data = await reader.read()
    writer.close()
    head, _, body = data.partition(b"\r\n\r\n")
    status = int(head.split(b" ", 2)[1])
    return status, body.decode("utf-8", "replace")


@pytest.fixture
async def agent() -> AsyncIterator[AgentServer]:
    catalog = shop(2)
    profile = Profile(list(catalog.devices), {}, {}, {})
    core = Agent(profile, AgentConfig(buffer_size=16), instance_id=99)
    for n in range(40):
        core.buffer.add_value("m1_Xpos" if n % 2 else "m2_Xpos", "2024-05-01T12:00:00Z", n)
    async with AgentServer(core, "127.0.0.1", 0) as server:
        yield server


@pytest.mark.parametrize("case", cases("requests.yaml"), ids=lambda c: c["name"])
async def test_each_bad_request_gets_its_error_over_http(
    agent: AgentServer,
    case: dict[str, Any],
    schemas: dict[str, Any],  # noqa: F811
) -> None:
    target = case["target"] + "x" * case.get("pad", 0)
    status, body = await raw_get(agent.port, target)
    code = case["expect"]["code"]
    assert status == HTTP_STATUS[ErrorCode(code)], body[:300]
    assert f'errorCode="{code}"' in body
    assert_valid(schemas, "Error", body)
    status, good = await raw_get(agent.port, "/laser1/current")
    assert status == 200 and "<MTConnectStreams" in good
