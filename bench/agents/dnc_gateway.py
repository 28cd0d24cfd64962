"""The gateway's side of the DNC benchmark: its serial delivery transport (gateway/jobs/delivery/transports/
serial.py, pyserial in a thread per line) sending to the simulated device servers, and the raw pyserial
write the load figure is compared with. This process's CPU is the gateway's in the fleet figure.

Commands: `load` (url, baud, program file): one load, seconds; `raw` (url, baud, program file): the framed
program written to the port in one call; `drip` (urls, baud, program files, buffer): one drip per line at
once; `restart` (url, baud, program file, line, repeats): a drip restarted at a line, the command's time
(CLOCK_MONOTONIC) per repeat.
"""

from __future__ import annotations

import argparse
import asyncio
import hashlib
import time
from pathlib import Path
from typing import Any

import serial

from bench.agents.protocol import process_stats, serve, setup_logging
from gateway.codecs.dnc import frame_program
from gateway.config.jobs import ControllerSerial
from gateway.jobs.delivery.transport import Program, Progress
from gateway.jobs.delivery.transports.serial import SerialTransport, request_restart
from gateway.jobs.dnc.port import line_settings


def settings(url: str, baud: int, **more: Any) -> ControllerSerial:
    return ControllerSerial.model_validate(
        {"type": "serial", "where": url, "baud": baud, "dc1_timeout": 30, **more}
    )


def program(path: Path) -> Program:
    data = path.read_bytes()
    return Program(path.name, path, len(data), hashlib.sha256(data).hexdigest(), None, "bench")


def ignore(_progress: Progress) -> None:
    pass


async def main(workdir: Path) -> None:
    async def load(request: dict[str, Any]) -> dict[str, Any]:
        line = SerialTransport(
            settings(request["url"], int(request["baud"])), machine="bench", state_dir=workdir
        )
        started = time.monotonic()
        try:
            await line.deliver(program(Path(request["program"])), ignore)
        finally:
            line.close()
        return {"seconds": time.monotonic() - started}

    def raw_write(url: str, baud: int, path: Path) -> float:
        line = line_settings(settings(url, baud))
        wire = line.encode(frame_program(path.read_bytes(), line).data)
        port = serial.serial_for_url(url, baudrate=baud, timeout=0, write_timeout=None)
        started = time.monotonic()
        try:
            port.write(wire)
            port.flush()
            written = time.monotonic() - started
            # Closing a socket:// port drops what the device server has not read yet: keep it open
            # until the line has carried it all (and a little longer).
            time.sleep(max(0.0, len(wire) / line.bytes_per_second - written) + 2.0)
        finally:
            port.close()
        return written

    async def raw(request: dict[str, Any]) -> dict[str, Any]:
        seconds = await asyncio.to_thread(
            raw_write, request["url"], int(request["baud"]), Path(request["program"])
        )
        return {"seconds": seconds}

    async def drip(request: dict[str, Any]) -> dict[str, Any]:
        urls: list[str] = request["urls"]
        files: list[str] = request["programs"]
        lines = [
            SerialTransport(
                settings(url, int(request["baud"]), mode="drip", buffer=int(request.get("buffer", 256))),
                machine=f"m{i:02d}",
                state_dir=workdir / f"m{i:02d}",
            )
            for i, url in enumerate(urls)
        ]
        before = process_stats()
        started = time.monotonic()
        try:
            results = await asyncio.gather(
                *(line.deliver(program(Path(f)), ignore) for line, f in zip(lines, files, strict=True)),
                return_exceptions=True,
            )
        finally:
            for line in lines:
                line.close()
        after = process_stats()
        failures = [f"{type(r).__name__}: {r}" for r in results if isinstance(r, BaseException)]
        wall = time.monotonic() - started
        return {"seconds": wall, "cpu_share": (after["cpu"] - before["cpu"]) / wall, "failures": failures}

    async def restart(request: dict[str, Any]) -> dict[str, Any]:
        path = Path(request["program"])
        prog = program(path)
        commands: list[float] = []
        for _ in range(int(request.get("repeats", 3))):
            line = SerialTransport(
                settings(request["url"], int(request["baud"]), mode="drip"),
                machine="bench",
                state_dir=workdir,
            )
            try:
                commands.append(time.monotonic())
                request_restart(path, int(request["line"]))  # the operator's command
                await line.deliver(prog, ignore)
            finally:
                line.close()
            await asyncio.sleep(float(request.get("pause", 0.5)))  # the controller back to reading
        return {"commands": commands}

    await serve({"load": load, "raw": raw, "drip": drip, "restart": restart})


if __name__ == "__main__":
    parser = argparse.ArgumentParser()
    parser.add_argument("--workdir", type=Path, required=True)
    setup_logging()
    args = parser.parse_args()
    asyncio.run(main(args.workdir))
