"""The simulator's FOCAS face answers an independent client: pyfocas (PyPI), pure sockets, written from
diohpix/pyfanuc's notes, not from our codec. Open, sysinfo, statinfo, macro read and write, over TCP.

A face that only agreed with our own client would prove little: pyfocas checks the frame header, the
exact frame length of each recv, the echo of device/path/function with six zero bytes, and decodes
numbers its own way (mantissa, base in byte 5, exponent in byte 7).
"""

from __future__ import annotations

import asyncio
from pathlib import Path

from pyfocas.protocol.protocol import FOCAS

from simulator.machine import MachineState
from tests.integration.focas.conftest import simulator


def _client_session(port: int) -> dict[str, object]:
    client = FOCAS("127.0.0.1", port)
    assert client.connect() is True
    try:
        out: dict[str, object] = {
            "sysinfo": client.get_sys_info(),
            "statinfo": client.get_status_info(),
            "before": client.read_macro(500, 502),
        }
        client.write_macro_double(501, -7.25)
        out["after"] = client.read_macro(500, 502)
        out["parts"] = client.read_macro(3901)
        return out
    finally:
        assert client.socket is not None
        client.socket.close()


async def test_pyfocas_reads_and_writes_the_simulator(tmp_path: Path) -> None:
    async with simulator(tmp_path) as sim:
        assert sim.focas is not None
        sim.machine.program.part_count = 17
        sim.focas.cnc.macros[500] = 3.5
        result = await asyncio.to_thread(_client_session, sim.focas.port)
        info = result["sysinfo"]
        assert (info.cnc_type, info.series, info.version, info.axes, info.max_axis) == (
            "31",
            "G4A1",
            "14.0",
            "3",
            8,
        )  # type: ignore[attr-defined]
        stat = result["statinfo"]
        assert sim.machine.state is MachineState.IDLE
        assert (stat.aut, stat.run, stat.emergency, stat.alarm) == (1, 0, 0, 0)  # type: ignore[attr-defined]
        assert result["before"] == {500: 3.5, 501: 0.0, 502: 0.0}
        assert result["after"] == {500: 3.5, 501: -7.25, 502: 0.0}
        assert sim.focas.cnc.macros[501] == -7.25  # pyfocas's write (function 0xA8, an IEEE double) landed
        assert result["parts"] == {3901: 17.0}
