"""`ShdrFace`: the simulator as an MTConnect adapter (SHDR over TCP, port 7878 by default).

What a Haas or Mazak adapter does, for the same machine the OPC UA server shows: an
agent connects, gets every value at once, then a line per tick with what changed, in
the controller's own units (mm, mm/min, W, bar, degC), stamped with the machine's
clock. The active alarms are the `system` condition: a FAULT (errors, fatal) or WARNING
per alarm, its number as the native code, its class as the native severity; NORMAL when
none is active. `* PING` gets `* PONG <period>`; an agent that stops pinging for two
periods is dropped. A client too slow to take the lines is dropped too (it reconnects
and gets everything again). Uses only gateway's pure SHDR codec.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import time
from collections.abc import Callable
from datetime import datetime
from typing import Self

from gateway.codecs.mtconnect.heartbeat import Action, AdapterHeartbeat
from gateway.codecs.mtconnect.shdr import Ping, ShdrReader, format_condition, format_pairs
from simulator.alarms import Severity
from simulator.errors import SimulatorError
from simulator.machine import Machine, MachineState, Mode

log = logging.getLogger("simulator.shdr")

DEFAULT_PORT = 7878
MAX_PENDING = 1 << 20  # bytes a client may fall behind before it is dropped

EXECUTION = {
    MachineState.IDLE: "READY",
    MachineState.RUNNING: "ACTIVE",
    MachineState.PAUSED: "FEED_HOLD",
    MachineState.ALARM: "STOPPED",
}
MODE = {Mode.AUTO: "AUTOMATIC", Mode.MANUAL: "MANUAL", Mode.MDA: "MANUAL_DATA_INPUT"}


def _number(value: float) -> str:
    return f"{value:.6g}" if abs(value) < 1e15 else repr(value)


def readings(m: Machine) -> dict[str, str]:
    """Every data item's SHDR value now (the keys of mappings/laser-sim-shdr.yaml)."""
    out = {"avail": "AVAILABLE", "estop": "TRIGGERED" if m.emergency_stop else "ARMED"}
    for axis in m.axes:
        n = axis.name
        out[f"{n}act"] = _number(axis.actual)
        out[f"{n}cmd"] = _number(axis.commanded)
        out[f"{n}feed"] = _number(abs(axis.velocity))
    out.update(
        path_feedrate=_number(m.feed_rate),
        feed_ovr=str(m.override),
        execution=EXECUTION[m.state],
        mode=MODE[m.mode],
        program=m.program.name,
        line=str(m.program.block),
        block=m.program.block_text,
        part_count=str(m.program.part_count),
        laser_on="ON" if m.laser.on else "OFF",
        laser_power=_number(m.laser.power_act),
        laser_power_cmd=_number(m.laser.power_set),
        gas_pressure=_number(m.laser.gas_pressure),
        head_temp=_number(m.laser.head_temp),
    )
    return out


def alarm_lines(m: Machine, stamp: datetime) -> bytes:
    if not m.alarms:
        return format_condition(stamp, "system", "NORMAL")
    lines = [
        format_condition(
            stamp,
            "system",
            "FAULT" if alarm.severity >= Severity.ERROR else "WARNING",
            native_code=str(alarm.id),
            native_severity=str(int(alarm.severity)),
            text=alarm.text,
        )
        for alarm in m.alarms
    ]
    return b"".join(lines)


class _Client:
    def __init__(self, reader: asyncio.StreamReader, writer: asyncio.StreamWriter, heartbeat_ms: int) -> None:
        self.reader = reader
        self.writer = writer
        self.heartbeat = AdapterHeartbeat(heartbeat_ms=heartbeat_ms)
        self.peer = str(writer.get_extra_info("peername"))


class ShdrFace:
    def __init__(
        self,
        machine: Machine,
        *,
        host: str = "127.0.0.1",
        port: int = DEFAULT_PORT,
        heartbeat_ms: int = 10_000,
        clock: Callable[[], datetime],
    ) -> None:
        self.machine = machine
        self.host = host
        self.port = port
        self.heartbeat_ms = heartbeat_ms
        self.clock = clock
        self.clients: set[_Client] = set()
        self.lines_sent = 0
        self._last: dict[str, str] = {}
        self._alarms: tuple[tuple[int, str, int], ...] | None = None
        self._server: asyncio.Server | None = None
        self._tasks: set[asyncio.Task[None]] = set()

    @property
    def url(self) -> str:
        return f"shdr://{self.host}:{self.port}"

    async def __aenter__(self) -> Self:
        try:
            self._server = await asyncio.start_server(self._serve, self.host, self.port)
        except OSError as exc:
            raise SimulatorError(
                f"SHDR adapter cannot listen on {self.host}:{self.port}: {exc.strerror or exc}"
            ) from None
        self.port = self._server.sockets[0].getsockname()[1]
        return self

    async def __aexit__(self, *exc_info: object) -> None:
        server, self._server = self._server, None
        if server is not None:
            server.close()
        for client in list(self.clients):
            client.writer.transport.abort()
        for task in list(self._tasks):
            task.cancel()
        if self._tasks:
            await asyncio.wait(self._tasks)
        if server is not None:
            with contextlib.suppress(Exception):
                await server.wait_closed()

    def snapshot(self) -> bytes:
        stamp = self.clock()
        values = readings(self.machine)
        return format_pairs(stamp, values.items()) + alarm_lines(self.machine, stamp)

    def publish(self) -> None:
        """What changed since the last tick, to every client (the runner calls it each tick)."""
        m = self.machine
        values = readings(m)
        changed = [(k, v) for k, v in values.items() if self._last.get(k) != v]
        self._last = values
        alarms = tuple((a.id, a.text, int(a.severity)) for a in m.alarms)
        alarms_changed = alarms != self._alarms
        self._alarms = alarms
        if not self.clients or (not changed and not alarms_changed):
            return
        stamp = self.clock()
        data = format_pairs(stamp, changed) if changed else b""
        if alarms_changed:
            data += alarm_lines(m, stamp)
        for client in list(self.clients):
            self._send(client, data)

    def _send(self, client: _Client, data: bytes) -> None:
        transport = client.writer.transport
        if transport.is_closing():
            return
        if transport.get_write_buffer_size() > MAX_PENDING:
            log.warning("SHDR client %s is too slow; dropping it", client.peer)
            transport.abort()
            return
        client.writer.write(data)
        self.lines_sent += data.count(b"\n")

    async def _serve(self, reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
        task = asyncio.current_task()
        assert task is not None
        self._tasks.add(task)
        client = _Client(reader, writer, self.heartbeat_ms)
        self.clients.add(client)
        log.info("SHDR agent connected from %s", client.peer)
        try:
            self._send(client, self.snapshot())
            await self._listen(client)
        except (ConnectionError, asyncio.IncompleteReadError):
            pass
        finally:
            self.clients.discard(client)
            self._tasks.discard(task)
            writer.transport.abort()
            log.info("SHDR agent %s gone", client.peer)

    async def _listen(self, client: _Client) -> None:
        lines = ShdrReader()
        heartbeat = client.heartbeat
        while True:
            try:
                async with asyncio.timeout(heartbeat.period):
                    data = await client.reader.read(4096)
            except TimeoutError:
                data = None
            now = time.monotonic()
            if data == b"":
                return
            if data:
                for event in lines.feed(data, self.clock()):
                    if isinstance(event, Ping):
                        self._send(client, heartbeat.on_ping(now))
            if heartbeat.poll(now) is Action.TIMED_OUT:
                log.info("SHDR agent %s stopped pinging; closing", client.peer)
                return
