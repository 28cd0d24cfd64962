"""`HaasMdcFace`: the simulator as a Haas NGC's machine data collection port (5051). Async context manager.

It answers Q-commands from the laser model (`?Q100` serial number ... `?Q500` program, status and
parts, `?Q600 n` macro and system variables: 5021-5023 machine and 5041-5043 work positions, 3027 the
spindle (the laser's power), 3901 parts, the common variables #100-#999 and #10000-#10999) and ?E writes
of the common variables, as a Haas does: each answer framed by STX and ETB, then CR LF and a `>`
prompt, and sent to **every** connected client (at most two; a third is closed at once). While a
program runs, Q500 answers `STATUS, BUSY`. Uses the gateway's pure MDC codec for the queries' format.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import re
from typing import Self

from gateway.codecs.haas_mdc.protocol import format_value
from simulator.errors import SimulatorError
from simulator.machine import Machine, MachineState, Mode

log = logging.getLogger("simulator.haas_mdc")

DEFAULT_PORT = 5051
MAX_CLIENTS = 2
MAX_LINE = 256
WRITABLE = ((100, 199), (500, 999), (10000, 10999))
_QUERY = re.compile(r"^\?Q(\d{3})(?:\s+(\d{1,5}))?$")
_WRITE = re.compile(r"^\?E(\d{1,5})\s+(-?\d+(?:\.\d*)?|-?\.\d+)$")
MODES = {Mode.AUTO: "MEM", Mode.MANUAL: "JOG", Mode.MDA: "MDI"}
STATES = {MachineState.IDLE: "IDLE", MachineState.PAUSED: "FEED HOLD", MachineState.ALARM: "ALARM ON"}


def _hms(seconds: float) -> str:
    s = int(seconds)
    return f"{s // 3600:05d}:{s // 60 % 60:02d}:{s % 60:02d}"


class HaasMdcFace:
    def __init__(self, machine: Machine, *, host: str = "127.0.0.1", port: int = DEFAULT_PORT,
                 serial: str = "1234567") -> None:  # fmt: skip
        self.machine = machine
        self.host, self.port, self.serial = host, port, serial
        self.macros: dict[int, float] = {}
        self.answers = 0
        self.refused = 0  # connections over the limit
        self._writers: set[asyncio.StreamWriter] = set()
        self._tasks: set[asyncio.Task[None]] = set()
        self._server: asyncio.Server | None = None

    @property
    def url(self) -> str:
        return f"mdc://{self.host}:{self.port}"

    async def __aenter__(self) -> Self:
        try:
            self._server = await asyncio.start_server(self._serve, self.host, self.port)
        except OSError as exc:
            raise SimulatorError(
                f"Haas MDC face cannot listen on {self.host}:{self.port}: {exc.strerror or exc}"
            ) from None
        self.port = self._server.sockets[0].getsockname()[1]
        return self

    async def __aexit__(self, *exc_info: object) -> None:
        server, self._server = self._server, None
        if server is not None:
            server.close()
        for writer in list(self._writers):
            writer.transport.abort()
        if self._tasks:  # the aborted connections end their handlers; cancel what is left
            await asyncio.wait(list(self._tasks), timeout=0.5)
        for task in list(self._tasks):
            task.cancel()
        if self._tasks:
            await asyncio.wait(self._tasks)
        if server is not None:
            with contextlib.suppress(Exception):
                await server.wait_closed()

    async def _serve(self, reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
        if len(self._writers) >= MAX_CLIENTS:
            self.refused += 1
            writer.transport.abort()
            return
        task = asyncio.current_task()
        assert task is not None
        self._tasks.add(task)
        self._writers.add(writer)
        buf = bytearray()
        try:
            while data := await reader.read(1024):
                for byte in data:
                    if byte in (0x0D, 0x0A):
                        if buf:
                            self._broadcast(self.answer(buf.decode("ascii", errors="replace").strip()))
                            buf.clear()
                    elif len(buf) < MAX_LINE:
                        buf.append(byte)
        except ConnectionError:
            pass
        finally:
            self._writers.discard(writer)
            self._tasks.discard(task)
            writer.transport.abort()

    def _broadcast(self, text: str) -> None:
        """As a Haas: the answer goes to every connected client, not only the asker."""
        frame = b"\x02" + text.encode("ascii", errors="replace") + b"\x17\r\n>"
        self.answers += 1
        for writer in list(self._writers):
            if not writer.is_closing():
                writer.write(frame)

    def answer(self, line: str) -> str:
        m = self.machine
        if q := _QUERY.match(line):
            number, var = int(q[1]), q[2]
            if number == 600 and var is not None:
                value = self.variable(int(var))
                return f"?, {line}" if value is None else f"MACRO, {format_value(value)}"
            if var is not None:
                return f"?, {line}"
            simple = {
                100: f"SERIAL NUMBER, {self.serial}", 101: "SOFTWARE VERSION, 100.24.000.1011",
                102: "MODEL, LASER-SIM", 104: f"MODE, {MODES[m.mode]}", 200: "TOOL CHANGES, 0",
                201: "USING TOOL, 1", 300: f"P.O. TIME, {_hms(m.sim_time)}",
                301: f"C.S.TIME, {_hms(m.program.run_time)}", 303: f"LAST CYCLE, {_hms(m.program.run_time)}",
                304: "PREV CYCLE, 00000:00:00", 402: f"M30 #1, {m.program.part_count}",
                403: f"M30 #2, {m.program.part_count}",
            }  # fmt: skip
            if number in simple:
                return simple[number]
            if number == 500:
                if m.state is MachineState.RUNNING:
                    return "STATUS, BUSY"
                return f"PROGRAM, {m.program.name or 'MDI'}, {STATES[m.state]}, PARTS, {m.program.part_count}"
            return f"?, {line}"
        if w := _WRITE.match(line):
            n, value = int(w[1]), float(w[2])
            if not any(lo <= n <= hi for lo, hi in WRITABLE):
                return f"?, {line}"
            self.macros[n] = value
            return "!"
        return f"?, {line}"

    def variable(self, n: int) -> float | None:
        m = self.machine
        axes = m.axes
        if 5021 <= n < 5021 + len(axes):
            return round(axes[n - 5021].actual, 4)
        if 5041 <= n < 5041 + len(axes):
            return round(axes[n - 5041].actual, 4)
        if n == 3027:
            return round(m.laser.power_act, 1)
        if n == 3901:
            return float(m.program.part_count)
        if any(lo <= n <= hi for lo, hi in WRITABLE):
            return self.macros.get(n, 0.0)
        return None
