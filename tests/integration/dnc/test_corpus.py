"""Every case of tests/corpus/dnc/controller.yaml: a scripted, misbehaving controller on a raw TCP port,
and the gateway's serial transport sending to it over socket:// with real pyserial."""

from __future__ import annotations

import asyncio
from pathlib import Path
from typing import Any

import pytest
import yaml

from gateway.errors import DeliveryError
from simulator.dnc import DeviceServer
from tests.integration.dnc.rig import Progresses, drip_program, program_file, transport

CORPUS = Path(__file__).resolve().parents[2] / "corpus" / "dnc" / "controller.yaml"
CASES: list[dict[str, Any]] = yaml.safe_load(CORPUS.read_text(encoding="utf-8"))
REPEAT = 0.2


class Controller:
    """Plays one case's script to each connection, and counts what it receives."""

    def __init__(self, case: dict[str, Any]) -> None:
        self.case = case
        self.received = 0

    async def serve(self, reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
        case = self.case
        opening = bytes.fromhex(case.get("hex", "")) * int(case.get("repeat", 1))
        # Said again every REPEAT s until something comes, as the simulator's DC1 (pyserial empties its
        # input when it opens a port, so the first may be lost).
        repeat = asyncio.create_task(self._repeat(writer, opening))
        try:
            await self._read(reader, writer, repeat)
        finally:
            repeat.cancel()

    async def _repeat(self, writer: asyncio.StreamWriter, opening: bytes) -> None:
        while opening and not self.received and not writer.is_closing():
            writer.write(opening)
            await asyncio.sleep(REPEAT)

    async def _read(
        self, reader: asyncio.StreamReader, writer: asyncio.StreamWriter, repeat: asyncio.Task[None]
    ) -> None:
        case = self.case
        after = case.get("after_bytes")
        close_after = case.get("close_after")
        try:
            while data := await reader.read(4096):
                before, self.received = self.received, self.received + len(data)
                if after is not None and before < after <= self.received:
                    writer.write(bytes.fromhex(case["after_hex"]))
                if close_after is not None and self.received >= close_after:
                    break
                await writer.drain()
        except ConnectionError:
            pass
        finally:
            writer.close()


@pytest.mark.parametrize("case", CASES, ids=[c["name"] for c in CASES])
async def test_a_misbehaving_controller_gets_a_clear_failure(case: dict[str, Any], tmp_path: Path) -> None:
    controller = Controller(case)
    server = await asyncio.start_server(controller.serve, "127.0.0.1", 0)
    port = server.sockets[0].getsockname()[1]
    expect = case["expect"]
    try:
        kind = DeviceServer(case.get("device_server", "transparent"))
        line = transport(
            f"socket://127.0.0.1:{port}", tmp_path, baud=9600, device_server=kind, **case.get("settings", {})
        )
        with pytest.raises(DeliveryError) as failed:
            await line.deliver(program_file(tmp_path, drip_program(100)), Progresses())
    finally:
        server.close()
        await server.wait_closed()
    exc = failed.value
    assert type(exc).__name__ in ("DeliveryError", "TransferFailed", "LineLost")
    assert expect["reason"] in exc.reason, exc.reason
    assert exc.permanent is expect["permanent"], exc.reason
    if "received_at_most" in expect:
        assert controller.received <= expect["received_at_most"]
