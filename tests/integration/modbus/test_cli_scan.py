"""`cnc-gateway modbus scan`: a device's registers in every layout, its holes named, a clear error when
nothing answers. Against the tests' own device (not pymodbus), as a user runs it: a process."""

from __future__ import annotations

import asyncio
import struct
import sys
from pathlib import Path

from gateway.codecs.modbus.address import Table
from tests.modbus_device import OddDevice
from tests.waiting import free_port

CLI = [sys.executable, "-m", "gateway.cli.main"]
ROOT = Path(__file__).resolve().parents[3]


async def run(*args: str) -> tuple[int, str, str]:
    proc = await asyncio.create_subprocess_exec(
        *CLI, *args, cwd=ROOT, stdout=asyncio.subprocess.PIPE, stderr=asyncio.subprocess.PIPE
    )
    out, err = await asyncio.wait_for(proc.communicate(), timeout=60)
    assert proc.returncode is not None
    return proc.returncode, out.decode(), err.decode()


async def test_scan_prints_every_layout_and_names_the_holes() -> None:
    device = OddDevice()
    words = struct.unpack(">2H", struct.pack(">f", 123.456))
    device.set(Table.HOLDING, 0, [words[1], words[0]])  # a CDAB float at 0
    device.set(Table.HOLDING, 2, [0x4C58])  # "LX"
    device.set(Table.HOLDING, 130, [0xFFFE])  # past the first request of 125, after a hole 3-129
    async with device:
        code, out, err = await run(
            "modbus", "scan", "127.0.0.1", "--port", str(device.port), "--range", "0-130"
        )
    assert code == 0, err
    lines = out.splitlines()
    assert "f32 CDAB" in lines[0] and "i32 DCBA" in lines[0]
    first = lines[1].split()
    assert first[:3] == ["0", "400001", "0xE979"]
    assert "123.456" in first  # in the CDAB column: the order this device uses
    assert lines[3].split()[:6] == ["2", "400003", "0x4C58", "19544", "19544", "LX"]
    assert lines[4].split()[:4] == ["3", "400004", "--", "ILLEGAL"]
    last = lines[-1].split()
    assert last[:5] == ["130", "400131", "0xFFFE", "65534", "-2"]
    assert len(lines) == 1 + 131
    # the holes were read one by one after the device refused the first request
    assert any(s.count == 125 for s in device.reads(3)) and any(
        s.address == 3 and s.count == 1 for s in device.reads(3)
    )


async def test_scan_of_coils_and_of_nothing() -> None:
    device = OddDevice()
    device.set(Table.COIL, 0, [1, 0, 1])
    async with device:
        code, out, _ = await run("modbus", "scan", "127.0.0.1", "--port", str(device.port), "--table", "coil",
                                 "--range", "0-2")  # fmt: skip
    assert code == 0
    assert [line.split()[-1] for line in out.splitlines()[1:]] == ["1", "0", "1"]
    code, _, err = await run("modbus", "scan", "127.0.0.1", "--port", str(free_port()), "--timeout", "0.5")
    assert code == 1 and "cannot connect to 127.0.0.1" in err and "Traceback" not in err
    code, _, err = await run("modbus", "scan", "127.0.0.1", "--range", "10-5")
    assert code == 2 and "first before last" in err
