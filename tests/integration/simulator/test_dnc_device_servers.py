"""The simulator's two raw-TCP device servers, with real pyserial over socket://.

A `7bit` device server (the default: a Moxa NPort or Lantronix whose port is set 7E2, as a Fanuc wants
it) does the parity in its UART: the controller's DC1 and DC3 reach the sender as 0x11 and 0x13, and
whatever the sender puts in bit 7 of a byte, the controller gets its low 7 bits with the right parity.
A `transparent` port carries 8-bit bytes: the parity bit travels as bit 7, so a sender without software
parity gives the controller parity errors (alarm 085).
"""

from __future__ import annotations

import asyncio
import socket
from pathlib import Path

import pytest

from gateway.codecs.dnc import DC1, DC3, frame_program
from simulator.alarms import DNC_COMMUNICATION
from simulator.dnc import DeviceServer, DncOptions, DncSpec, Mode
from simulator.machine import MachineState
from simulator.runner import Simulator
from tests.integration.simulator.dnc_sender import send
from tests.integration.simulator.test_dnc import (
    LINE,
    LOAD,
    RATE,
    ROOMY,
    SOFT,
    alarm_ids,
    drip_program,
    face,
    simulator,
)
from tests.waiting import free_port, wait_until

SEVEN = DeviceServer.SEVEN_BIT
TRANSPARENT = DeviceServer.TRANSPARENT


async def test_a_7bit_device_server_hands_the_controllers_dc1_and_dc3_on_as_0x11_and_0x13(
    tmp_path: Path,
) -> None:
    # 40 moves of 20 mm at 3000 mm/min: 0.4 s each (0.1 s at speed 4), 22 bytes each (6 ms on the line):
    # the buffer fills up to DC3 long before the machine needs the rest.
    program = drip_program(40, 20.0, 3000)
    async with simulator(tmp_path, SEVEN, mode=Mode.DRIP, **ROOMY) as sim:
        sent = await asyncio.to_thread(send, face(sim).socket_url, program, LINE, rate=RATE)
        assert sent.sender.done and sent.dc3_seen >= 1 and sent.dc1_seen >= 2
        assert set(sent.heard) == {DC1, DC3}  # 0x11 and 0x13: no parity bit in bit 7, nothing else
        stats = face(sim).stats()
        assert stats["device_server"] == "7bit" and stats["dc3_sent"] >= 1
        assert stats["parity_errors"] == 0 and stats["overflows"] == 0 and stats["device_errors"] == 0
        await wait_until(lambda: face(sim).stats()["drips"] == 1 and sim.machine.state is MachineState.IDLE,
                         timeout=30, message="the drip program to end")  # fmt: skip
        assert list(face(sim).controller.executed) == program.split(b"\n")[1:-2]  # every block, as sent


@pytest.mark.parametrize("sender", ["software parity", "plain 7-bit", "bit 7 set on every byte"])
async def test_a_7bit_device_server_gives_the_controller_the_low_7_bits_without_parity_errors(
    tmp_path: Path, sender: str
) -> None:
    data = frame_program(LOAD, LINE).data
    wire = {
        "software parity": SOFT.encode(data),
        "plain 7-bit": data,
        "bit 7 set on every byte": bytes(b | 0x80 for b in data),
    }[sender]
    async with simulator(tmp_path, SEVEN) as sim:
        with socket.create_connection(("127.0.0.1", face(sim).tcp_port or 0)) as sock:
            sock.sendall(wire)  # the device server's buffer and TCP hold what the line has not taken yet
            await wait_until(lambda: sim.programs.exists("O4711"), timeout=30, message="O4711 stored")
        assert sim.programs.read("O4711").encode() == LOAD
        assert face(sim).stats()["parity_errors"] == 0 and not sim.machine.alarms


@pytest.mark.parametrize(("kind", "errors"), [(TRANSPARENT, True), (SEVEN, False)])
async def test_a_sender_without_software_parity_needs_a_7bit_device_server(
    tmp_path: Path, kind: DeviceServer, errors: bool
) -> None:
    async with simulator(tmp_path, kind) as sim:
        await asyncio.to_thread(send, face(sim).socket_url, LOAD, LINE, rate=RATE, timeout=20)
        if errors:
            # Plain 7-bit characters through an 8-bit port: bit 7 lands on the parity bit.
            await wait_until(lambda: DNC_COMMUNICATION in alarm_ids(sim), message="alarm 085")
            assert face(sim).stats()["parity_errors"] > 0 and not sim.programs.exists("O4711")
        else:
            await wait_until(lambda: sim.programs.exists("O4711"), message="O4711 stored")
            assert face(sim).stats()["parity_errors"] == 0 and not sim.machine.alarms


async def test_the_override_of_the_options_is_the_machines(tmp_path: Path) -> None:
    options = DncOptions(DncSpec(line=LINE), tcp_port=0, rfc2217_port=None, override=800)
    async with Simulator(opcua_port=free_port(), ftp_port=free_port(), store=tmp_path, dnc=options) as sim:
        assert sim.machine.override == 800 and face(sim).stats()["override"] == 800
        assert face(sim).stats()["device_server"] == "7bit"  # the default kind
