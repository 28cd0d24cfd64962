"""The integrator's tools against a running gateway, as separate processes: listen, and encode --send."""

from __future__ import annotations

import asyncio
import os
import signal
import sys
from pathlib import Path

from tests.integration.copydata.conftest import RigFactory, targets
from tests.waiting import wait_until

ROOT = Path(__file__).resolve().parents[3]
CLI = str(Path(sys.executable).parent / "cnc-gateway")
MAPPING = str(ROOT / "mappings" / "laser-sim.yaml")
NESTING = {
    "name": "nesting",
    "transport": "tcp-server",
    "bind": "127.0.0.1",
    "port": 0,
    "accept_writes": True,
}


async def test_frames_listen_prints_the_head_moving_and_stops_cleanly_on_sigint(make_rig: RigFactory) -> None:
    rig = await make_rig(targets(NESTING), loop_program="demo.nc")
    port = await rig.server_port()
    proc = await asyncio.create_subprocess_exec(
        CLI, "frames", "listen", "--tcp", f"127.0.0.1:{port}", "--mapping", MAPPING,
        stdout=asyncio.subprocess.PIPE, stderr=asyncio.subprocess.PIPE,
        env={**os.environ, "PYTHONUNBUFFERED": "1"},
    )  # fmt: skip
    lines: list[str] = []
    try:
        assert proc.stdout is not None

        async def read_lines() -> None:
            assert proc.stdout is not None
            while line := await proc.stdout.readline():
                lines.append(line.decode())

        reader = asyncio.create_task(read_lines())
        marker = "Axes/X/Position="
        await wait_until(
            lambda: len({text.split(marker)[1].split()[0] for text in lines if marker in text}) > 5,
            timeout=20,
            message="several X positions printed",
        )
        assert "dwData=2" in lines[0] and "Program/Name=" in lines[0]  # the snapshot names every variable
        proc.send_signal(signal.SIGINT)
        async with asyncio.timeout(15):
            code = await proc.wait()
        await reader
        assert proc.stderr is not None
        err = (await proc.stderr.read()).decode()
        assert code == 0, err
        assert "Traceback" not in err and "connected to 127.0.0.1" in err
    finally:
        if proc.returncode is None:
            proc.kill()
            await proc.wait()


async def test_frames_encode_send_writes_through_an_accept_writes_target(make_rig: RigFactory) -> None:
    rig = await make_rig(targets(NESTING))
    await rig.connected()
    port = await rig.server_port()
    proc = await asyncio.create_subprocess_exec(
        CLI, "frames", "encode", "--mapping", MAPPING, "Feed/Override=42", "--send", f"127.0.0.1:{port}",
        stdout=asyncio.subprocess.PIPE, stderr=asyncio.subprocess.PIPE,
    )  # fmt: skip
    async with asyncio.timeout(30):
        out, err = await proc.communicate()
    assert proc.returncode == 0, err.decode()
    assert out.decode().strip() == "01 00 00 00 06 00 00 00 06 00 02 00 2a 00"
    assert "sent 14 bytes" in err.decode()
    await wait_until(lambda: rig.sim.machine.override == 42, message="the simulator's override at 42")
