"""The connection guard both HTTP faces listen through (gateway/sinks/http_listener.py), over real loopback
sockets from several source addresses: the per-address cap, the global cap that closes the oldest waiting
connection to make room (and refuses when every one is busy), the header timeout (TLS handshake
included), the keep-alive, a response nobody reads, and the share of the open-file limit."""

from __future__ import annotations

import asyncio
import logging
import ssl
from collections.abc import AsyncIterator
from contextlib import asynccontextmanager
from pathlib import Path

import pytest
from aiohttp import web

from gateway.sinks import http_listener
from gateway.sinks.http_listener import Limits, Listener, descriptor_share
from tests.integration.web.test_api import _self_signed
from tests.waiting import wait_until

BOUND = 5.0  # s: generous; only catches a connection the guard never closes


@asynccontextmanager
async def serving(
    limits: Limits, tls: ssl.SSLContext | None = None
) -> AsyncIterator[tuple[Listener, asyncio.Event]]:
    """A listener whose `/hold` waits for the event, `/big` sends 32 MiB, anything else answers 200."""
    release = asyncio.Event()

    async def handle(request: web.Request) -> web.StreamResponse:
        if request.path == "/hold":
            await release.wait()
        if request.path == "/big":
            return web.Response(body=b"x" * (32 * 1024 * 1024))
        return web.Response(text="ok")

    app = web.Application()
    app.router.add_route("*", "/{tail:.*}", handle)
    listener = Listener(name="test face", limits=limits, tls=tls)
    await listener.start(app, "127.0.0.1", 0)
    try:
        yield listener, release
    finally:
        release.set()
        await listener.stop()


async def connect(port: int, source: str = "127.0.0.1") -> tuple[asyncio.StreamReader, asyncio.StreamWriter]:
    return await asyncio.open_connection("127.0.0.1", port, local_addr=(source, 0))


async def get(port: int, path: str = "/", source: str = "127.0.0.1") -> bytes:
    reader, writer = await connect(port, source)
    try:
        writer.write(f"GET {path} HTTP/1.1\r\nHost: t\r\nConnection: close\r\n\r\n".encode())
        return await asyncio.wait_for(reader.read(), BOUND)
    finally:
        writer.close()


async def closed(reader: asyncio.StreamReader) -> bytes:
    """What the server sent before it closed the connection (it must close it within BOUND)."""
    return await asyncio.wait_for(reader.read(), BOUND)


async def test_one_address_gets_its_share_and_no_more_while_others_are_served() -> None:
    async with serving(Limits(max=100, per_address=3)) as (listener, _):
        held = [await connect(listener.port, "127.0.0.2") for _ in range(3)]
        reader, writer = await connect(listener.port, "127.0.0.2")
        refused = await closed(reader)
        writer.close()
        assert refused.startswith(b"HTTP/1.1 503 ") and b"too many connections" in refused
        assert (await get(listener.port, source="127.0.0.3")).startswith(b"HTTP/1.1 200 ")
        assert listener.guard.counts["refused: per-address cap"] == 1
        for _, w in held:
            w.close()


async def test_at_the_cap_the_oldest_waiting_connection_makes_room_for_a_new_request() -> None:
    async with serving(Limits(max=4, per_address=100)) as (listener, _):
        silent = [await connect(listener.port, f"127.0.0.{10 + n}") for n in range(4)]
        await wait_until(lambda: len(listener.guard.open) == 4, timeout=BOUND)
        answer = await get(listener.port)
        assert answer.startswith(b"HTTP/1.1 200 ")
        assert await closed(silent[0][0]) == b""  # the oldest one, closed for room
        assert listener.guard.counts["closed to make room"] >= 1
        assert len(listener.guard.open) <= 4
        for _, w in silent:
            w.close()


async def test_when_every_connection_is_busy_a_new_one_is_refused() -> None:
    async with serving(Limits(max=3, per_address=100)) as (listener, release):
        busy = []
        for n in range(3):
            reader, writer = await connect(listener.port, f"127.0.0.{20 + n}")
            writer.write(b"GET /hold HTTP/1.1\r\nHost: t\r\n\r\n")
            busy.append((reader, writer))
        await wait_until(lambda: not listener.guard.waiting and len(listener.guard.open) == 3, timeout=BOUND)
        reader, writer = await connect(listener.port, "127.0.0.30")
        assert (await closed(reader)).startswith(b"HTTP/1.1 503 ")
        writer.close()
        release.set()
        for reader, writer in busy:  # and the busy ones were served to the end
            assert (await asyncio.wait_for(reader.readuntil(b"ok"), BOUND)).startswith(b"HTTP/1.1 200 ")
            writer.close()


async def test_headers_that_do_not_arrive_in_time_get_408_and_a_prompt_request_is_served() -> None:
    async with serving(Limits(header_timeout=0.3, keepalive=30)) as (listener, _):
        reader, writer = await connect(listener.port)
        writer.write(b"GET / HTTP/1.1\r\nHost: t\r\nX-Slow: 1\r\n")  # and never the blank line
        assert (await closed(reader)).startswith(b"HTTP/1.1 408 ")
        writer.close()
        assert listener.guard.counts["header timeouts"] == 1
        assert (await get(listener.port)).startswith(b"HTTP/1.1 200 ")


async def test_an_idle_connection_is_closed_after_the_keepalive() -> None:
    async with serving(Limits(header_timeout=30, keepalive=0.3)) as (listener, _):
        reader, writer = await connect(listener.port)
        writer.write(b"GET / HTTP/1.1\r\nHost: t\r\n\r\n")
        assert (await asyncio.wait_for(reader.readuntil(b"ok"), BOUND)).startswith(b"HTTP/1.1 200 ")
        assert await closed(reader) == b""
        writer.close()


async def test_a_response_nobody_reads_is_aborted(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(http_listener, "STALLED_SEND", 0.3)
    async with serving(Limits()) as (listener, _):
        _, writer = await connect(listener.port)
        writer.transport.pause_reading()  # reads nothing: the server's send buffer fills
        writer.write(b"GET /big HTTP/1.1\r\nHost: t\r\n\r\n")
        await wait_until(lambda: listener.guard.counts["stalled sends"] == 1, timeout=BOUND)
        await wait_until(lambda: not listener.guard.open, timeout=BOUND)
        writer.close()


async def test_tls_handshakes_are_capped_and_timed_out_like_the_rest(tmp_path: Path) -> None:
    _self_signed(tmp_path)
    server = ssl.create_default_context(ssl.Purpose.CLIENT_AUTH)
    server.load_cert_chain(tmp_path / "http-cert.pem", tmp_path / "http-key.pem")
    client = ssl.create_default_context(cafile=str(tmp_path / "http-cert.pem"))
    client.check_hostname = False
    async with serving(Limits(header_timeout=1.0, per_address=2), tls=server) as (listener, _):
        reader, writer = await asyncio.open_connection("127.0.0.1", listener.port, ssl=client)
        writer.write(b"GET / HTTP/1.1\r\nHost: t\r\nConnection: close\r\n\r\n")
        assert (await asyncio.wait_for(reader.read(), BOUND)).startswith(b"HTTP/1.1 200 ")
        writer.close()
        silent = [await connect(listener.port, "127.0.0.40") for _ in range(2)]  # no handshake at all
        third_reader, third = await connect(listener.port, "127.0.0.40")
        assert await closed(third_reader) == b""  # over the per-address cap: closed, no plain-text reply
        for r, w in silent:  # and the two that never shook hands are closed at the header timeout
            assert await closed(r) == b""
            w.close()
        third.close()
        await wait_until(lambda: not listener.guard.open, timeout=BOUND)
        assert listener.guard.counts["header timeouts"] == 2


def test_a_cap_above_the_share_of_the_open_file_limit_is_lowered(caplog: pytest.LogCaptureFixture) -> None:
    share = descriptor_share()
    with caplog.at_level(logging.WARNING, "gateway.http"):
        guard = http_listener.Guard("test face", Limits(max=share + 1000))
    assert guard.max == share
    assert f"connections.max {share + 1000} is lowered to {share}" in caplog.text
    assert http_listener.Guard("test face", Limits(max=5)).max == 5
    assert http_listener.Guard("test face", Limits()).max == share
