"""`cnc-simulator` as users run it: a subprocess on free ports, stopped with a signal."""

from __future__ import annotations

import asyncio
import signal
import socket
import sys
from pathlib import Path

import pytest

from tests.opcua_client import Client
from tests.waiting import free_port, wait_until


def command() -> list[str]:
    script = Path(sys.executable).with_name("cnc-simulator")
    return [str(script)] if script.exists() else [sys.executable, "-m", "simulator.cli"]


def listening(port: int) -> bool:
    with socket.socket() as s:
        s.settimeout(0.2)
        return s.connect_ex(("127.0.0.1", port)) == 0


@pytest.mark.parametrize("sig", [signal.SIGINT, signal.SIGTERM])
async def test_serves_and_stops_cleanly_on_a_signal(tmp_path: Path, sig: signal.Signals) -> None:
    opcua, ftp = free_port(), free_port()
    proc = await asyncio.create_subprocess_exec(
        *command(),
        "--opcua-port",
        str(opcua),
        "--ftp-port",
        str(ftp),
        "--store",
        str(tmp_path),
        "--speed",
        "10",
        stdout=asyncio.subprocess.PIPE,
        stderr=asyncio.subprocess.PIPE,
    )
    try:
        await wait_until(
            lambda: listening(ftp) and listening(opcua), timeout=20, message="the simulator to listen"
        )
        async with Client(f"opc.tcp://127.0.0.1:{opcua}", timeout=5) as client:
            state = await client.get_node("ns=2;s=::AsGlobalPV:gMachine.StateText").read_value()
        assert state == "Idle"
        proc.send_signal(sig)
        out, err = await asyncio.wait_for(proc.communicate(), 10)
    finally:
        if proc.returncode is None:
            proc.kill()
            await proc.wait()
    assert proc.returncode == 0
    assert "Traceback" not in err.decode()
    assert (
        f"opc.tcp://127.0.0.1:{opcua}" in out.decode()
        and f"ftp://127.0.0.1:{ftp}/DATA/Programs" in out.decode()
    )
    assert (tmp_path / "DATA" / "Programs" / "demo.nc").is_file()


async def test_port_in_use_is_a_clear_error(tmp_path: Path) -> None:
    with socket.socket() as busy:
        busy.bind(("127.0.0.1", 0))
        busy.listen()
        port = busy.getsockname()[1]
        proc = await asyncio.create_subprocess_exec(
            *command(),
            "--opcua-port",
            str(port),
            "--ftp-port",
            str(free_port()),
            "--store",
            str(tmp_path),
            stdout=asyncio.subprocess.PIPE,
            stderr=asyncio.subprocess.PIPE,
        )
        _, err = await asyncio.wait_for(proc.communicate(), 20)
    assert proc.returncode == 1
    text = err.decode()
    assert f"cannot start: OPC UA server cannot listen on 127.0.0.1:{port}" in text
    assert "Traceback" not in text
