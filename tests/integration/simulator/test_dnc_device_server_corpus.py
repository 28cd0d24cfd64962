"""Every case of tests/corpus/dnc/device_server.yaml, through each kind of the simulator's raw-TCP device
server over a real socket: what the controller makes of junk on the wire, and that it takes a good
program afterwards (after a Reset, as an operator would, when an alarm stopped it)."""

from __future__ import annotations

import asyncio
import contextlib
import logging
import socket
from collections.abc import AsyncIterator
from pathlib import Path
from typing import Any

import pytest
import yaml

from gateway.codecs.dnc import LineSettings
from simulator.dnc import DeviceServer, DncFace, DncSpec, Mode
from simulator.machine import Machine
from simulator.store import MemoryStore
from tests.waiting import wait_until

CORPUS = Path(__file__).resolve().parents[2] / "corpus" / "dnc" / "device_server.yaml"
CASES: list[dict[str, Any]] = yaml.safe_load(CORPUS.read_text(encoding="utf-8"))
LINE = LineSettings(baud=9600)  # 7E2
SOFT = LineSettings(baud=9600, software_parity=True)
SPEED = 10.0
GOOD = b"%\nO0001 (AFTER THE JUNK)\nG1 X1 F100\nM30\n%\n"
HONEST = {DeviceServer.SEVEN_BIT: LINE, DeviceServer.TRANSPARENT: SOFT}  # what each kind needs sent


def wire(case: dict[str, Any]) -> bytes:
    if "hex" in case:
        return bytes.fromhex(case["hex"])
    text = str(case["text"]).encode("utf-8")
    bit7 = case.get("bit7")
    if bit7 == "set":
        return bytes(b | 0x80 for b in text)
    if bit7 == "parity":
        return SOFT.encode(text)
    return text


@contextlib.asynccontextmanager
async def controller(kind: DeviceServer) -> AsyncIterator[DncFace]:
    spec = DncSpec(line=LINE, mode=Mode.LOAD, buffer_size=1024, high_water=768, low_water=256)
    face = DncFace(spec, Machine(MemoryStore()), MemoryStore(), tcp_port=0, speed=SPEED, device_server=kind)
    async with face:
        yield face


async def send(face: DncFace, data: bytes, *, close_after: int | None = None) -> None:
    """Write `data` (or its first `close_after` bytes) to the device server, once the controller has seen
    every character of it, close the connection."""
    before = face.controller.stats.rx_chars
    part = data if close_after is None else data[:close_after]
    _reader, writer = await asyncio.open_connection("127.0.0.1", face.tcp_port)
    try:
        await wait_until(lambda: face.controller.connected, message="the link")
        writer.write(part)
        await writer.drain()
        if close_after is None:
            await wait_until(
                lambda: face.controller.stats.rx_chars >= before + len(part),
                timeout=20,
                message="every character on the line",
            )
    finally:
        writer.close()
        with contextlib.suppress(ConnectionError):
            await writer.wait_closed()
    await wait_until(lambda: not face.controller.connected, timeout=20, message="the link closed")


@pytest.mark.parametrize("kind", list(DeviceServer), ids=[k.value for k in DeviceServer])
@pytest.mark.parametrize("case", CASES, ids=[c["name"] for c in CASES])
async def test_junk_into_a_device_server_is_a_counted_error_never_a_crash(
    case: dict[str, Any], kind: DeviceServer, caplog: pytest.LogCaptureFixture
) -> None:
    expect = case["expect"][kind.value]
    data = wire(case)
    caplog.set_level(logging.ERROR, logger="simulator.dnc")
    async with controller(kind) as face:
        c, machine = face.controller, face.machine
        half = len(data) // 2 if case.get("then") == "close_half_way" else None
        stored_before = c.stats.programs_loaded
        if half is None:
            # Judged while the link is up: closing it may rightly raise 86 for a program left open.
            before = c.stats.rx_chars
            with socket.create_connection(("127.0.0.1", face.tcp_port or 0)) as sock:
                await wait_until(lambda: c.connected, message="the link")
                await asyncio.to_thread(sock.sendall, data)
                await wait_until(lambda: c.stats.rx_chars >= before + len(data), timeout=20,
                                 message="every character on the line")  # fmt: skip
                judge(face, expect, stored_before)
            await wait_until(lambda: not c.connected, timeout=20, message="the link closed")
        else:
            await send(face, data, close_after=half)
            judge(face, expect, stored_before)
        # Still a working controller: Reset (as an operator would after an alarm), then a good program.
        machine.reset()
        face.kick()
        await send(face, HONEST[kind].encode(GOOD))
        await wait_until(
            lambda: face.stats()["last_loaded"] == "O0001", timeout=20, message="the good program"
        )
    assert not [r for r in caplog.records if r.levelno >= logging.ERROR], caplog.text


def judge(face: DncFace, expect: dict[str, Any], stored_before: int) -> None:
    s = face.stats()
    alarms = [a.id for a in face.machine.alarms]
    seen = {k: s[k] for k in ("stage", "parity_errors", "junk", "programs_loaded", "last_loaded")} | {
        "alarms": alarms
    }
    if expect["stored"] is None:
        assert s["programs_loaded"] == stored_before, seen
    else:
        assert s["programs_loaded"] == stored_before + 1 and s["last_loaded"] == expect["stored"], seen
    assert alarms == ([] if expect["alarm"] is None else [expect["alarm"]]), seen
    if "parity_errors" in expect:
        assert s["parity_errors"] == expect["parity_errors"], seen
    if "parity_errors_at_least" in expect:
        assert s["parity_errors"] >= expect["parity_errors_at_least"], seen
    if "junk_at_least" in expect:
        assert s["junk"] >= expect["junk_at_least"], seen
