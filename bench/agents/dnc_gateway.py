"""The gateway's side of the DNC benchmark: its serial delivery transport (gateway/jobs/delivery/transports/
serial.py, pyserial in a thread per line) sending to the simulated device servers, and the raw pyserial
write the load figure is compared with. This process's CPU is the gateway's in the fleet figure.

Commands: `load` (url, baud, program file): one load, seconds; `raw` (url, baud, program file): the framed
program written to the port in one call; `drip` (urls, baud, program files, buffer, link, record): one drip
per line at once, the lines in one fleet (gateway/jobs/dnc/fleet.py; `link`: they share a device
server of that capacity), with `record` the time (CLOCK_MONOTONIC) and size of every write the transport made;
`sent_after` (holds: [from, to or null], CLOCK_MONOTONIC): the characters the transport wrote
within each hold, from the last recorded drip; `restart` (url, baud, program file, line, repeats): a drip
restarted at a line, the command's time (CLOCK_MONOTONIC) per repeat.
"""

from __future__ import annotations

import argparse
import asyncio
import bisect
import hashlib
import itertools
import math
import time
from array import array
from pathlib import Path
from typing import Any

import serial

from bench.agents.protocol import process_stats, serve, setup_logging
from gateway.codecs.dnc import frame_program
from gateway.config.jobs import ControllerSerial
from gateway.jobs.delivery.transport import Program, Progress
from gateway.jobs.delivery.transports.serial import SerialTransport, request_restart
from gateway.jobs.dnc.fleet import DripFleet
from gateway.jobs.dnc.port import SerialPort, line_settings


class WriteLog:
    """Every write the serial transport makes while recording: when (just before the call, so that a write
    racing a DC3 counts as after it) and how many characters the port took. One line's worth (the overrun
    figure drips one program); a few million writes are a few tens of MB in two arrays."""

    def __init__(self) -> None:
        self.times = array("d")
        self.counts = array("q")
        self.on = False
        self._write = SerialPort.write

        def write(port: SerialPort, data: bytes) -> int:
            if not self.on:
                return self._write(port, data)
            now = time.monotonic()
            n = self._write(port, data)
            self.times.append(now)
            self.counts.append(n)
            return n

        SerialPort.write = write  # type: ignore[method-assign]

    def start(self) -> None:
        self.times, self.counts, self.on = array("d"), array("q"), True

    def within(self, holds: list[list[float | None]]) -> list[int]:
        """Characters written after each hold's DC3 and before its DC1."""
        totals = [0, *itertools.accumulate(self.counts)]
        out = []
        for start, end in holds:
            assert start is not None
            a = bisect.bisect_right(self.times, start)
            b = bisect.bisect_left(self.times, math.inf if end is None else end)
            out.append(totals[b] - totals[a])
        return out


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
    log = WriteLog()

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
        link = request.get("link")  # {"name": …, "capacity": chars/s}: the lines share one device server
        shared = {"link": link["name"], "link_capacity": float(link["capacity"])} if link else {}
        line_settings_ = [
            settings(url, int(request["baud"]), mode="drip", buffer=int(request.get("buffer", 256)), **shared)
            for url in urls
        ]
        fleet = DripFleet.for_lines((f"m{i:02d}", s) for i, s in enumerate(line_settings_))
        lines = [
            SerialTransport(s, machine=f"m{i:02d}", state_dir=workdir / f"m{i:02d}", fleet=fleet)
            for i, s in enumerate(line_settings_)
        ]
        log.on = False
        if request.get("record"):
            log.start()
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
        log.on = False
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

    def sent_after(request: dict[str, Any]) -> dict[str, Any]:
        return {"counts": log.within(request["holds"]), "writes": len(log.times)}

    await serve({"load": load, "raw": raw, "drip": drip, "sent_after": sent_after, "restart": restart})


if __name__ == "__main__":
    parser = argparse.ArgumentParser()
    parser.add_argument("--workdir", type=Path, required=True)
    setup_logging()
    args = parser.parse_args()
    asyncio.run(main(args.workdir))
