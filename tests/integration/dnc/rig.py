"""A simulator with its serial DNC face, and the gateway's serial transport pointed at it.

The simulator's line runs at `SIM_BAUD` times its speed factor; over socket:// (a
raw TCP device server, which carries no line settings) the gateway paces at that
effective rate, so its `baud` is `SIM_BAUD * SPEED`. The pseudo-terminal tests
run the simulator at speed 1, where the pty's baud rate must match the line's.

The device server is a `transparent` 8-bit port unless a test asks for the `7bit`
kind (as a device server set 7E2 is, the simulator's default), and the gateway is
configured for it as a user would (`AS_A_USER`): `software_parity: true` on a
transparent port, the defaults on a 7-bit one.
"""

from __future__ import annotations

import hashlib
from collections.abc import AsyncIterator
from contextlib import asynccontextmanager
from pathlib import Path
from typing import Any

import yaml

from bench.gcode_gen import paced_program
from gateway.codecs.dnc import LineSettings
from gateway.transports.base import Program, Progress
from gateway.transports.dnc.config import ControllerSerial
from gateway.transports.dnc.transport import SerialTransport
from simulator.dnc import DeviceServer, DncFace, DncOptions, DncSpec, Mode
from simulator.runner import Simulator
from tests.waiting import free_port

SIM_BAUD = 19200
SPEED = 4.0
#: The controller's buffer in these tests. The simulator sends its DC3 when its loop gets round to it,
#: which on a loaded machine can be tens of milliseconds late; characters that were on the line in the
#: meantime count as "after DC3" there. A roomy buffer keeps that from raising 087 in tests about other
#: things (as the simulator's own tests do); the gateway's own count (`Outcome.after_dc3_max`, what it
#: wrote after it had read a DC3) is the sender's measure.
ROOMY = {"buffer_size": 1024, "high_water": 256, "low_water": 64}
GATEWAY_BUFFER = 1024


def drip_program(blocks: int, *, step: float = 0.5, feed: int = 600) -> bytes:
    """A program whose blocks each take a moment to cut: header, one rapid, `blocks` feed moves, M30."""
    moves = b"".join(b"G1 X%.1f Y20 F%d\n" % (10 + step * (i + 1), feed) for i in range(blocks))
    return b"%\nO0042 (DRIP)\nG21 G90\nG0 X10 Y20\n" + moves + b"M30\n%\n"


def load_program(blocks: int = 60) -> bytes:
    return (
        b"%\nO4711 (BRACKET)\nG21 G90\n"
        + b"".join(b"G1 X%d Y20 F3000\n" % (10 + i % 100) for i in range(blocks))
        + b"M30\n%\n"
    )


#: The gateway's settings for a line through each kind of device server, as the README has a user set it.
AS_A_USER: dict[DeviceServer, dict[str, Any]] = {
    DeviceServer.SEVEN_BIT: {},
    DeviceServer.TRANSPARENT: {"software_parity": True},
}


@asynccontextmanager
async def simulator(
    tmp_path: Path,
    *,
    speed: float = SPEED,
    pty: bool = False,
    device_server: DeviceServer = DeviceServer.TRANSPARENT,
    override: int | None = None,
    baud: int = SIM_BAUD,
    **spec: Any,
) -> AsyncIterator[Simulator]:
    line = LineSettings(baud=baud)
    spec = {**ROOMY, **spec}
    options = DncOptions(
        DncSpec(line=line, **spec), tcp_port=0, rfc2217_port=None, pty=pty, device_server=device_server,
        override=override,
    )  # fmt: skip
    async with Simulator(
        opcua_port=free_port(), ftp_port=free_port(), speed=speed, store=tmp_path / "sim", dnc=options
    ) as sim:
        yield sim


def face(sim: Simulator) -> DncFace:
    assert sim.dnc is not None
    return sim.dnc


def settings(
    where: str,
    *,
    baud: float = SIM_BAUD * SPEED,
    device_server: DeviceServer = DeviceServer.TRANSPARENT,
    **more: Any,
) -> ControllerSerial:
    """A serial line's settings: `more` over what a user sets for a socket:// line through `device_server`."""
    kind = AS_A_USER[device_server] if where.startswith("socket://") else {}
    return ControllerSerial.model_validate(
        {"type": "serial", "where": where, "baud": int(baud), **kind, **more}
    )


def user_mapping(
    where: str,
    device_server: DeviceServer,
    *,
    baud: int,
    mode: str = "drip",
    punch: dict[str, Any] | None = None,
    **controller: Any,
) -> str:
    """A serial machine's mapping as a user writes it from the README for a line through `device_server`
    (`software_parity: true` only for a transparent port): `controller` adds keys (buffer, ...)."""
    serial = {"type": "serial", "where": where, "baud": baud, "mode": mode}
    serial |= AS_A_USER[device_server] | controller
    jobs: dict[str, Any] = {"controller": serial, "validation": {"dialect": "laser-sim"}, "max_attempts": 1}
    if punch is not None:
        jobs["punch"] = punch
    return yaml.safe_dump(
        {
            "machine": "lathe",
            "driver": {
                "endpoint": f"opc.tcp://127.0.0.1:{free_port()}",
                "reconnect": {"initial": 0.2, "max": 1},
            },
            "variables": [
                {"path": "Machine/State", "source": "ns=2;s=::AsGlobalPV:gMachine.State", "type": "Int16"}
            ],
            "jobs": jobs,
        },
        sort_keys=False,
    )


def program_file(tmp_path: Path, data: bytes, name: str = "part.nc") -> Program:
    path = tmp_path / f"{name}.program"
    path.write_bytes(data)
    return Program(name, path, len(data), hashlib.sha256(data).hexdigest(), None, "tester")


class Progresses(list[Progress]):
    def __call__(self, progress: Progress) -> None:
        self.append(progress)


def transport(where: str, tmp_path: Path, **more: Any) -> SerialTransport:
    more.setdefault("buffer", GATEWAY_BUFFER)
    return SerialTransport(settings(where, **more), machine="serial", state_dir=tmp_path / "state")


__all__ = ["Mode", "paced_program"]


def body_lines(data: bytes) -> list[bytes]:
    """The program's lines between its `%` lines, as the controller's interpreter gets them."""
    lines = data.split(b"\n")
    start = lines.index(b"%") + 1
    end = lines.index(b"%", start)
    return lines[start:end]


def line_index(data: bytes, number: int) -> int:
    """Index in `body_lines` of the program's source line `number` (1-based, the file's own numbering)."""
    return number - 2  # line 1 is the opening `%`
