"""The serial delivery transport against the simulator's DNC face, with real pyserial (socket://, a pty)."""

from __future__ import annotations

from pathlib import Path

from gateway.transports.dnc.transfer import AHEAD
from tests.integration.dnc.rig import (
    SIM_BAUD,
    Mode,
    Progresses,
    body_lines,
    drip_program,
    face,
    load_program,
    program_file,
    simulator,
    transport,
)
from tests.waiting import wait_until


async def test_load_over_socket_stores_the_program_byte_for_byte(tmp_path: Path) -> None:
    data = load_program()
    async with simulator(tmp_path) as sim:
        line = transport(face(sim).socket_url or "", tmp_path)
        progress = Progresses()
        where = await line.deliver(program_file(tmp_path, data), progress)
        assert "loaded" in where
        await wait_until(lambda: sim.programs.exists("O4711"), message="O4711 in the program store")
        assert sim.programs.read("O4711").encode() == data
        assert progress and progress[-1].sent == progress[-1].sent
        stats = face(sim).stats()
        assert stats["parity_errors"] == 0 and stats["overflows"] == 0 and not sim.machine.alarms


async def test_drip_larger_than_the_buffer_honours_dc3(tmp_path: Path) -> None:
    data = drip_program(400, feed=300)
    async with simulator(tmp_path, mode=Mode.DRIP) as sim:
        line = transport(face(sim).socket_url or "", tmp_path, mode="drip")
        progress = Progresses()
        await line.deliver(program_file(tmp_path, data), progress)
        stats = face(sim).stats()
        assert len(data) > 5 * 1024  # five times the controller's buffer
        assert stats["dc3_sent"] > 0 and stats["overflows"] == 0 and stats["rx_chars"] >= len(data)
        assert line.last is not None and line.last.pauses > 0
        assert line.last.after_dc3_max <= AHEAD  # what the gateway wrote after it had read a DC3
        assert any(p.block for p in progress) and any(p.lead for p in progress)
        await wait_until(lambda: sim.machine.state.name == "IDLE", timeout=30, message="drip ran to M30")
        assert not sim.machine.alarms


async def test_load_and_drip_over_a_pseudo_terminal_device_path(tmp_path: Path) -> None:
    # A pty carries no parity: the 7E2 line's parity bit travels as bit 7 (software_parity), and the
    # simulator reads the baud rate pyserial set on it, so the line runs at its real rate (speed 1).
    data = load_program(30)
    async with simulator(tmp_path, speed=1.0, pty=True) as sim:
        path = face(sim).pty_path
        assert path.startswith("/dev/")
        line = transport(path, tmp_path, baud=SIM_BAUD, software_parity=True)
        await line.deliver(program_file(tmp_path, data), Progresses())
        await wait_until(lambda: sim.programs.exists("O4711"), message="O4711 in the program store")
        assert sim.programs.read("O4711").encode() == data
        assert face(sim).stats()["parity_errors"] == 0
        face(sim).set_mode("drip")
        drip = drip_program(40)
        mark = len(face(sim).controller.executed)
        line = transport(path, tmp_path, baud=SIM_BAUD, software_parity=True, mode="drip")
        await line.deliver(program_file(tmp_path, drip, "drip.nc"), Progresses())
        await wait_until(
            lambda: list(face(sim).controller.executed)[mark:] == body_lines(drip),
            timeout=30,
            message="the drip program ran, line for line",
        )
