"""The simulator's serial DNC face with real pyserial ports: socket://, rfc2217:// and a pty device path.

Each test starts a Simulator with its DNC face on free ports and talks to it
with the honest sender of dnc_sender.py (run in a thread, since pyserial blocks),
or with one of its faulty variants. The line runs at 9600 baud times the
simulator's speed. Flow-control margins are generous where the test is about
something else, so that a busy machine cannot make an honest sender look bad.
"""

from __future__ import annotations

import asyncio
import dataclasses
from collections.abc import AsyncIterator
from contextlib import asynccontextmanager
from pathlib import Path

import pytest
from asyncua import ua

from gateway.codecs.dnc import (
    LineSettings,
    ProgramReceived,
    RemoteRequest,
    frame_program,
    not_found,
    parse_request,
)
from simulator.alarms import DNC_BUFFER_OVERFLOW, DNC_COMMUNICATION, DNC_LINE_DROPPED
from simulator.dnc import DeviceServer, DncOptions, DncSpec, Mode
from simulator.machine import MachineState
from simulator.runner import Simulator
from tests.integration.simulator.dnc_sender import receive, send
from tests.opcua_client import Client
from tests.waiting import free_port, wait_until

SPEED = 4.0
LINE = LineSettings(baud=9600)  # 7E2
SOFT = dataclasses.replace(LINE, software_parity=True)  # a transparent port and a pty: parity as bit 7
RATE = LINE.bytes_per_second * SPEED  # characters per real second
ROOMY = {"buffer_size": 1024, "high_water": 256, "low_water": 64}  # room for any scheduling hiccup
D = "ns=2;s=::DNC:"

LOAD = (
    b"%\nO4711 (BRACKET)\nG21 G90\n"
    + b"".join(b"G1 X%d Y20 F3000\n" % (10 + i) for i in range(60))
    + b"M30\n%\n"
)


def drip_program(blocks: int, step: float, feed: int) -> bytes:
    moves = b"".join(b"G1 X%.1f Y20 F%d\n" % (10 + step * (i + 1), feed) for i in range(blocks))
    return b"%\nO0042 (DRIP)\nG21 G90\nG0 X10 Y20\n" + moves + b"M30\n%\n"


@asynccontextmanager
async def simulator(
    tmp_path: Path, device_server: DeviceServer = DeviceServer.TRANSPARENT, **spec: object
) -> AsyncIterator[Simulator]:
    """The tests below send with software parity (SOFT) on raw TCP: a transparent port, said so; the 7-bit
    device server has its own tests (test_dnc_device_servers.py)."""
    options = DncOptions(
        DncSpec(line=LINE, **spec),
        tcp_port=0,
        rfc2217_port=0,
        pty=True,
        device_server=device_server,  # type: ignore[arg-type]
    )
    async with Simulator(
        opcua_port=free_port(), ftp_port=free_port(), speed=SPEED, store=tmp_path, dnc=options
    ) as sim:
        yield sim


def face(sim: Simulator):  # type: ignore[no-untyped-def]
    assert sim.dnc is not None
    return sim.dnc


def alarm_ids(sim: Simulator) -> list[int]:
    return [a.id for a in sim.machine.alarms]


# --- load ------------------------------------------------------------------------------------------


async def test_load_over_a_raw_tcp_device_server_stores_the_program(tmp_path: Path) -> None:
    async with simulator(tmp_path) as sim:
        sent = await asyncio.to_thread(send, face(sim).socket_url, LOAD, SOFT, rate=RATE)
        assert sent.sender.done and sent.dc1_seen >= 1
        await wait_until(lambda: sim.programs.exists("O4711"), message="O4711 in the program store")
        stored = sim.programs.read("O4711").encode()
        assert stored == LOAD
        assert (
            sim.store / "DATA" / "Programs" / "O4711"
        ).read_bytes() == LOAD  # where the FTP face serves it
        assert face(sim).stats()["programs_loaded"] == 1 and not sim.machine.alarms


async def test_load_over_rfc2217_with_the_controllers_settings(tmp_path: Path) -> None:
    async with simulator(tmp_path) as sim:
        sent = await asyncio.to_thread(send, face(sim).rfc2217_url, LOAD, LINE, rate=RATE)
        assert sent.sender.done
        await wait_until(lambda: sim.programs.exists("O4711"), message="O4711 in the program store")
        assert sim.programs.read("O4711").encode() == LOAD
        assert face(sim).stats()["parity_errors"] == 0


async def test_rfc2217_sender_with_the_wrong_parity_gets_alarm_085(tmp_path: Path) -> None:
    async with simulator(tmp_path) as sim:
        wrong = LineSettings.from_format("8N1", LINE)  # the device server's UART now runs 8N1 at 9600
        await asyncio.to_thread(send, face(sim).rfc2217_url, LOAD, wrong, rate=RATE, timeout=10)
        await wait_until(lambda: DNC_COMMUNICATION in alarm_ids(sim), message="alarm 085")
        assert face(sim).stats()["parity_errors"] > 0
        assert not sim.programs.exists("O4711")


async def test_raw_tcp_sender_without_the_parity_bit_gets_parity_errors(tmp_path: Path) -> None:
    async with simulator(tmp_path) as sim:
        # Plain 7-bit characters, no parity bit: what a sender set to 8N1 puts on a 7E2 line.
        await asyncio.to_thread(send, face(sim).socket_url, LOAD, LINE, rate=RATE, timeout=10)
        await wait_until(lambda: DNC_COMMUNICATION in alarm_ids(sim), message="alarm 085")
        assert face(sim).stats()["parity_errors"] > 0 and sim.machine.state is MachineState.ALARM


async def test_a_dropped_line_during_a_load_raises_086_and_stores_nothing(tmp_path: Path) -> None:
    async with simulator(tmp_path) as sim:
        sent = await asyncio.to_thread(send, face(sim).socket_url, LOAD, SOFT, rate=RATE, stop_after=300)
        assert sent.closed_early
        await wait_until(lambda: DNC_LINE_DROPPED in alarm_ids(sim), message="alarm 086")
        assert face(sim).stats()["line_drops"] == 1 and not sim.programs.exists("O4711")


# --- drip ------------------------------------------------------------------------------------------


async def test_drip_feed_over_a_pty_runs_the_program_with_flow_control(tmp_path: Path) -> None:
    # 40 moves of 20 mm at 3000 mm/min: 0.4 s each (0.1 s at speed 4), 22 bytes each (6 ms on the line).
    program = drip_program(40, 20.0, 3000)
    async with simulator(tmp_path, mode=Mode.DRIP, **ROOMY) as sim:
        parts = sim.machine.program.part_count
        sent = await asyncio.to_thread(send, face(sim).pty_path, program, SOFT, rate=RATE)
        assert sent.sender.done
        # The buffer filled up to DC3 long before the machine needed the rest: the sender was held back.
        assert sent.dc3_seen >= 1 and sent.dc1_seen >= 2
        await wait_until(lambda: sim.machine.program.part_count == parts + 1, timeout=30, message="the part")
        assert sim.machine.axes[0].actual == pytest.approx(810.0)
        stats = face(sim).stats()
        assert stats["starvations"] == 0 and stats["dc3_sent"] >= 1 and stats["drips"] == 1
        assert not sim.machine.alarms


async def test_a_sender_that_ignores_dc3_overflows_the_buffer_alarm_087(tmp_path: Path) -> None:
    program = drip_program(200, 20.0, 3000)  # far more than 256 bytes of buffer, and slow to run
    async with simulator(tmp_path, mode=Mode.DRIP) as sim:
        await asyncio.to_thread(
            send, face(sim).socket_url, program, SOFT, rate=RATE, ignore_dc3=True, timeout=30
        )
        await wait_until(lambda: DNC_BUFFER_OVERFLOW in alarm_ids(sim), message="alarm 087")
        stats = face(sim).stats()
        assert stats["overflows"] == 1 and stats["after_dc3_max"] > 32
        assert sim.machine.state is MachineState.ALARM


async def test_a_sender_too_slow_for_the_program_starves_the_drip_feed(tmp_path: Path) -> None:
    # 1 mm moves at 6000 mm/min run in 10 ms (2.5 ms at speed 4); this sender gives 100 characters a second.
    program = drip_program(24, 1.0, 6000)
    async with simulator(tmp_path, mode=Mode.DRIP, buffer_size=128, high_water=96, low_water=32) as sim:
        await asyncio.to_thread(send, face(sim).socket_url, program, SOFT, rate=100.0, timeout=60)
        await wait_until(lambda: sim.machine.state is MachineState.IDLE and face(sim).stats()["drips"] == 1,
                         timeout=30, message="the drip program to end")  # fmt: skip
        assert face(sim).stats()["starvations"] >= 1
        assert sim.machine.starvations == face(sim).stats()["starvations"]
        assert sim.machine.axes[0].actual == pytest.approx(34.0)


# --- punch and remote requests, commanded over OPC UA ----------------------------------------------


async def test_punch_commanded_over_opcua_arrives_framed(tmp_path: Path) -> None:
    async with simulator(tmp_path) as sim, Client(sim.opcua_endpoint, timeout=5) as client:
        receiving = asyncio.create_task(asyncio.to_thread(receive, face(sim).socket_url, SOFT, rate=RATE))
        await wait_until(lambda: face(sim).stats()["link"] != "", message="the link")
        await client.get_node(D + "punch").write_value(ua.Variant("demo.nc", ua.VariantType.String))
        events = await receiving
        received = [e for e in events if isinstance(e, ProgramReceived)]
        expected = frame_program(sim.programs.read("demo.nc").encode(), SOFT)
        assert received[0].text == expected.data[expected.body_start : expected.body_end]
        assert await client.get_node(D + "txChars").read_value() == len(expected.data)


async def test_punch_of_a_missing_program_is_refused_over_opcua(tmp_path: Path) -> None:
    async with simulator(tmp_path) as sim, Client(sim.opcua_endpoint, timeout=5) as client:
        with pytest.raises(ua.UaStatusCodeError) as info:  # type: ignore[attr-defined]
            await client.get_node(D + "punch").write_value(ua.Variant("missing.nc", ua.VariantType.String))
        assert "BadInvalidState" in str(info.value) or "BadInvalidArgument" in str(info.value)


@pytest.mark.parametrize("known", [True, False])
async def test_remote_request_is_answered_and_the_answer_loaded(tmp_path: Path, known: bool) -> None:
    async with simulator(tmp_path) as sim, Client(sim.opcua_endpoint, timeout=5) as client:
        name = "O4711" if known else "O0815"
        answer = LOAD if known else not_found(name)
        receiving = asyncio.create_task(
            asyncio.to_thread(receive, face(sim).socket_url, SOFT, rate=RATE, answer=answer)
        )
        await wait_until(lambda: face(sim).stats()["link"] != "", message="the link")
        await client.get_node(D + "request").write_value(ua.Variant(name, ua.VariantType.String))
        events = await receiving
        request = next(e for e in events if isinstance(e, ProgramReceived))
        assert parse_request(request.text) == RemoteRequest(name)
        if known:
            await wait_until(lambda: sim.programs.exists("O4711"), message="the answer in the store")
            assert sim.programs.read("O4711").encode() == LOAD
        else:
            await wait_until(lambda: face(sim).stats()["request_reply"], message="the answer's comment")
            assert face(sim).stats()["request_reply"] == "NOT FOUND O0815"
            assert await client.get_node(D + "requestReply").read_value() == "NOT FOUND O0815"


# --- cnc-simulator ---------------------------------------------------------------------------------


async def test_cnc_simulator_serves_dnc_on_the_ports_it_is_given(tmp_path: Path) -> None:
    import signal
    import time

    import serial

    from tests.integration.simulator.test_cli import command, listening

    opcua, ftp, dnc = free_port(), free_port(), free_port()
    proc = await asyncio.create_subprocess_exec(
        *command(), "--opcua-port", str(opcua), "--ftp-port", str(ftp), "--store", str(tmp_path),
        "--dnc-port", str(dnc), "--dnc-baud", "19200", "--dnc-format", "8N1", "--dnc-mode", "drip",
        stdout=asyncio.subprocess.PIPE, stderr=asyncio.subprocess.PIPE,
    )  # fmt: skip

    def first_byte() -> bytes:
        """The first byte the controller sends. `listening()` connected too: until the simulator has seen
        that probe go, the port (one cable) refuses another link, so a refused link is tried again."""
        deadline = time.monotonic() + 10
        while time.monotonic() < deadline:
            try:
                with serial.serial_for_url(f"socket://127.0.0.1:{dnc}", timeout=0) as port:
                    while time.monotonic() < deadline:
                        if data := port.read(1):
                            return bytes(data)
                        time.sleep(0.01)
            except serial.SerialException:
                time.sleep(0.05)
        return b""

    try:
        await wait_until(lambda: listening(dnc) and listening(opcua), timeout=20, message="the simulator")
        assert await asyncio.to_thread(first_byte) == b"\x11"  # DC1: ready to read, 8N1 has no parity bit
        async with Client(f"opc.tcp://127.0.0.1:{opcua}", timeout=5) as client:
            assert await client.get_node(D + "line").read_value() == "19200 8N1 xonxoff"
            assert await client.get_node(D + "mode").read_value() == "drip"
        proc.send_signal(signal.SIGINT)
        out, err = await asyncio.wait_for(proc.communicate(), 10)
    finally:
        if proc.returncode is None:
            proc.kill()
            await proc.wait()
    assert proc.returncode == 0 and "Traceback" not in err.decode()
    assert f"socket://127.0.0.1:{dnc}" in out.decode() and "a 7-bit device server" in out.decode()
    assert "rfc2217://" not in out.decode()  # the test suite turns the default 4002 off
