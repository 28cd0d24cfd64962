"""`S7Face`: the laser's PLC over S7comm (python-snap7's server; port 1102 by default: 102 needs privileges).

What a SINUMERIK's or a laser cell's PLC holds, for the same machine the OPC UA server shows, in data
blocks as TIA Portal lays out non-optimized ones (mappings/laser-sim-s7.yaml reads them):

DB10 (the machine, read):            DB20 (commands, written by the gateway):
  0 REAL X   4 REAL Y   8 REAL Z       0 INT   feed override setpoint (%), applied at the next tick
 12 REAL feed rate (mm/min)            2.0 BOOL feed hold (true: pause, false: resume)
 16 REAL laser power (W)               4 STRING[32] a message for the operator (kept, shown in DB10)
 20 REAL gas pressure (bar)
 24 REAL head temperature (degC)     M: M0.0 toggles every second (a heartbeat), MW2 counts ticks
 28 INT state   30 INT override      I: I0.0 door closed, I0.1 e-stop released
 32 DINT part count                  Q: Q4.0 shutter open (laser on), Q4.1 gas valve open
 36.0 laser on .1 e-stop .2 running .3 alarm
 38 STRING[32] program name
 72 DATE_AND_TIME the PLC's clock (UTC)
 80 LREAL run time (s)   88 UDINT block number   92 STRING[32] the operator message (from DB20)

The tick copies the machine into the areas (under snap7's area locks) and applies DB20's commands;
snap7's server threads answer the clients. One correction to snap7's server: it writes a BIT item as a
whole byte, where a CPU sets only that bit (so a BOOL written by the gateway would clear its neighbours);
`_BitServer` sets the bit.
"""

from __future__ import annotations

import asyncio
import logging
import struct
from collections.abc import Callable
from datetime import datetime
from typing import Any, Self

import snap7
from snap7.datatypes import S7WordLen
from snap7.error import S7Error
from snap7.type import SrvArea

from gateway.codecs.s7.address import Area, Field, Kind
from gateway.codecs.s7.layout import encode
from gateway.errors import RequestError
from simulator.errors import SimulatorError
from simulator.machine import Machine, MachineState

log = logging.getLogger("simulator.s7")

DEFAULT_PORT = 1102
MACHINE_DB = 10
COMMAND_DB = 20
_STRING32 = Field(Area.DB, MACHINE_DB, 0, 34, Kind.STRING, length=32)
_DT = Field(Area.DB, MACHINE_DB, 0, 8, Kind.DATE_AND_TIME)


class _BitServer(snap7.Server):
    """snap7's server, writing BIT items as a CPU does: one bit, not the byte (see the module doc)."""

    def _parse_address_specification(self, addr_spec: bytes) -> dict[str, Any]:
        spec: dict[str, Any] = super()._parse_address_specification(addr_spec)
        if spec and spec.get("word_len") == S7WordLen.BIT and len(addr_spec) >= 12:
            spec["bit"] = int.from_bytes(addr_spec[9:12], "big") & 7
        return spec

    def _parse_write_address(self, request: dict[str, Any]) -> Any:
        parsed = super()._parse_write_address(request)
        spec = (request.get("parameters") or {}).get("address_spec") or {}
        if parsed is None or spec.get("word_len") != S7WordLen.BIT:
            return parsed
        area, db, start, count, data = parsed
        memory = self.memory_areas.get((area, db))
        if memory is None or start >= len(memory):
            return parsed
        mask = 1 << spec.get("bit", 0)
        value = memory[start] | mask if data[0] & 1 else memory[start] & ~mask & 0xFF
        return area, db, start, count, bytearray((value,))


class S7Face:
    def __init__(
        self,
        machine: Machine,
        *,
        host: str = "127.0.0.1",
        port: int = DEFAULT_PORT,
        clock: Callable[[], datetime],
        blocks: dict[int, bytearray] | None = None,
    ) -> None:
        self.machine = machine
        self.host = host
        self.port = port
        self.clock = clock
        self.db10 = bytearray(128)
        self.db20 = bytearray(64)
        self.flags = bytearray(16)
        self.inputs = bytearray(8)
        self.outputs = bytearray(8)
        self.blocks = blocks or {}  # more data blocks, served as they are (tests, benchmarks)
        self.ticks = 0
        self.message = ""
        self._override: int | None = None
        self._hold: bool | None = None
        self._server: _BitServer | None = None

    @property
    def url(self) -> str:
        return f"s7://{self.host}:{self.port}/0/1"

    async def __aenter__(self) -> Self:
        server = _BitServer(log=False)
        server.register_area(SrvArea.DB, MACHINE_DB, self.db10)
        server.register_area(SrvArea.DB, COMMAND_DB, self.db20)
        server.register_area(SrvArea.MK, 0, self.flags)
        server.register_area(SrvArea.PE, 0, self.inputs)
        server.register_area(SrvArea.PA, 0, self.outputs)
        for number, block in self.blocks.items():
            server.register_area(SrvArea.DB, number, block)
        self.db20[0:2] = struct.pack(">h", self.machine.override)
        self.db20[4:38] = encode(_STRING32, "")
        self._override = self.machine.override
        self._hold = False
        self.publish()
        try:
            await asyncio.to_thread(server.start_to, self.host, self.port)
        except (S7Error, OSError, ValueError) as exc:
            raise SimulatorError(f"S7 face cannot listen on {self.host}:{self.port}: {exc}") from None
        assert server.server_socket is not None
        self.port = server.server_socket.getsockname()[1]
        self._server = server
        return self

    async def __aexit__(self, *exc_info: object) -> None:
        server, self._server = self._server, None
        if server is not None:
            await asyncio.to_thread(server.stop)

    def _locked(self, area: SrvArea, index: int) -> Any:
        server = self._server

        class _Lock:
            def __enter__(self) -> None:
                if server is not None:
                    server.lock_area(area, index)

            def __exit__(self, *exc: object) -> None:
                if server is not None:
                    server.unlock_area(area, index)

        return _Lock()

    def publish(self) -> None:
        """The tick: DB20's commands to the machine, the machine into DB10 and the I/O (each locked)."""
        self._commands()
        m = self.machine
        self.ticks += 1
        db = bytearray(self.db10)
        x, y, z = (axis.actual for axis in m.axes)
        laser = m.laser
        struct.pack_into(">fffffff", db, 0, x, y, z, m.feed_rate, laser.power_act, laser.gas_pressure,
                         laser.head_temp)  # fmt: skip
        struct.pack_into(">hhi", db, 28, int(m.state), m.override, m.program.part_count)
        running = m.state is MachineState.RUNNING
        db[36] = int(laser.on) | int(m.emergency_stop) << 1 | int(running) << 2 | int(bool(m.alarms)) << 3
        db[38:72] = encode(_STRING32, m.program.name[:32].encode("latin-1", "replace").decode("latin-1"))
        db[72:80] = encode(_DT, self.clock())
        struct.pack_into(">dI", db, 80, m.program.run_time, m.program.block)
        db[92:126] = encode(_STRING32, self.message)
        with self._locked(SrvArea.DB, MACHINE_DB):
            self.db10[:] = db
        with self._locked(SrvArea.MK, 0):
            self.flags[0] = (self.flags[0] & ~1) | (int(self.clock().timestamp()) & 1)
            struct.pack_into(">H", self.flags, 2, self.ticks & 0xFFFF)
        with self._locked(SrvArea.PE, 0):
            self.inputs[0] = 0b01 | int(not m.emergency_stop) << 1
        with self._locked(SrvArea.PA, 0):
            self.outputs[4] = int(laser.on) | int(laser.gas_pressure > 0.1) << 1

    def _commands(self) -> None:
        with self._locked(SrvArea.DB, COMMAND_DB):
            override = struct.unpack_from(">h", self.db20, 0)[0]
            hold = bool(self.db20[2] & 1)
            declared, current = self.db20[4], self.db20[5]
            message = bytes(self.db20[6 : 6 + min(declared, current, 32)]).decode("latin-1")
        m = self.machine
        if override != self._override:
            self._override = override
            try:
                m.set_override(override)
            except RequestError as exc:  # a PLC ignores a setpoint it cannot take
                log.info("S7: override %s not taken: %s", override, exc.reason)
        if hold != self._hold:
            self._hold = hold
            try:
                if hold and m.state is MachineState.RUNNING:
                    m.pause()
                elif not hold and m.state is MachineState.PAUSED:
                    m.resume()
            except RequestError as exc:  # as a PLC ignores a command the machine cannot take now
                log.info("S7: feed hold %s not taken: %s", hold, exc.reason)
        self.message = message
