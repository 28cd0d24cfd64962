"""One TCP connection to one Modbus device, through pymodbus: the adapter, and the only module that
imports it. Its errors become the gateway's here:

- an exception response is `DeviceRefused` (its code, the specification's name, the status it maps to);
- an answer of the wrong size or function is `Unexpected`: that request failed, the stream is in step;
- no answer within `timeout`, a lost connection, or bytes that are not Modbus TCP are `LinkLost`: the
  connection cannot be trusted any more and is closed; the source reconnects with its backoff.

Frames are checked before pymodbus sees them (`_Guard`): one for another transaction or another unit
is dropped and counted (pymodbus would log each at ERROR), and the reason goes into the timeout's
message; one that cannot be decoded ends the connection here instead of inside asyncio's
`data_received`, where pymodbus' exception would be logged as a fatal error with a traceback.
pymodbus' own reconnecting is off (`reconnect_delay=0`) and it does not retry (`retries=0`): the
source decides, with gateway.reconnect's backoff.
"""

from __future__ import annotations

import logging
from collections.abc import Sequence
from typing import Any, cast

from pymodbus.client import AsyncModbusTcpClient
from pymodbus.exceptions import ModbusException
from pymodbus.pdu import ModbusPDU

from gateway.codecs.modbus.address import Table
from gateway.codecs.modbus.frames import MBAP, exception_name, exception_status
from gateway.errors import SourceError
from gateway.shims.cancel import deliver_cancel

log = logging.getLogger("gateway.sources.modbus")


class _Demote(logging.Filter):
    """pymodbus logs each timeout and each frame it skips at ERROR, with a hex dump; the driver reports
    every failure itself, once, in its own words (OutageLog), so pymodbus' lines go to DEBUG."""

    def filter(self, record: logging.LogRecord) -> bool:
        if record.levelno > logging.DEBUG:
            record.levelno, record.levelname = logging.DEBUG, "DEBUG"
        return True


logging.getLogger("pymodbus.logging").addFilter(_Demote())

_READ = {Table.COIL: 1, Table.DISCRETE: 2, Table.HOLDING: 3, Table.INPUT: 4}


class DeviceRefused(SourceError):
    """The device answered with an exception response."""

    def __init__(self, function: int, code: int, what: str) -> None:
        self.function = function
        self.code = code
        self.name = exception_name(code)
        super().__init__(f"{what}: {self.name} (exception {code})", status=exception_status(code))


class Unexpected(SourceError):
    """An answer that does not fit its request (too few values, another function)."""


class LinkLost(SourceError):
    """The connection cannot be used any more (closed, silent, or garbled)."""


class _Guard:
    """Checks each complete frame's MBAP header before pymodbus' framer takes it (see the module doc)."""

    def __init__(self, client: AsyncModbusTcpClient, unit: int) -> None:
        self.ctx: Any = client.ctx  # the TransactionManager; its callback_data is replaced below
        self.unit = unit
        self.dropped = 0
        self.last_drop = ""
        self.garbled: str | None = None
        self._inner = self.ctx.callback_data
        setattr(self.ctx, "callback_data", self.callback_data)  # noqa: B010 - an instance's method, replaced

    def callback_data(self, data: bytes, addr: tuple[Any, ...] | None = None) -> int:
        used = 0
        ctx = self.ctx
        while len(data) - used >= MBAP.size:
            tid, protocol, length, unit = MBAP.unpack_from(data, used)
            if protocol != 0 or not 2 <= length <= 254:
                return self._garble(
                    f"bytes that are not Modbus TCP (protocol id {protocol}, length {length})", data
                )
            end = used + 6 + length
            if end > len(data):
                break
            expected = ctx.request_transaction_id
            if tid != expected or (unit != self.unit and self.unit != 0):
                self.dropped += 1
                self.last_drop = (
                    f"a frame for transaction {tid} (expected {expected})"
                    if tid != expected
                    else f"an answer from unit {unit} (expected {self.unit})"
                )
                used = end
                continue
            try:
                taken = self._inner(data[used:end], addr)
            except ModbusException as exc:
                return self._garble(f"an answer pymodbus cannot decode ({exc})", data)
            used += taken or end - used
        return used

    def _garble(self, reason: str, data: bytes) -> int:
        self.garbled = reason
        future = self.ctx.response_future
        if not future.done():
            future.set_exception(LinkLost(reason, status="BadCommunicationError"))
        transport = self.ctx.transport
        if transport is not None:
            transport.close()
        return len(data)


class ModbusLink:
    def __init__(self, host: str, port: int, unit: int, timeout: float) -> None:
        self.host = host
        self.port = port
        self.unit = unit
        self.timeout = timeout
        self.requests = 0
        self._client: AsyncModbusTcpClient | None = None
        self._guard: _Guard | None = None

    @property
    def where(self) -> str:
        return f"{self.host}:{self.port} unit {self.unit}"

    @property
    def connected(self) -> bool:
        return self._client is not None and self._client.connected

    @property
    def dropped(self) -> int:
        """Frames dropped in this connection (another transaction or unit)."""
        return self._guard.dropped if self._guard is not None else 0

    async def connect(self) -> None:
        self.close()
        client = AsyncModbusTcpClient(
            self.host,
            port=self.port,
            timeout=self.timeout,
            retries=0,
            reconnect_delay=0,
            name=f"modbus {self.host}:{self.port}",
            trace_connect=self._lost,
        )
        self._client = client
        self._guard = _Guard(client, self.unit)
        try:
            ok = await client.connect()
        except (OSError, ModbusException) as exc:  # pymodbus says False for most, but not for all
            ok = False
            log.debug("connect to %s: %s", self.where, exc)
        if not ok or not client.connected:
            self.close()
            raise LinkLost(f"cannot connect to {self.host}:{self.port}", status="BadNotConnected")

    def close(self) -> None:
        client, self._client = self._client, None
        if client is not None:
            client.close()

    def _lost(self, connected: bool) -> None:
        """pymodbus' trace_connect: a request waiting on a lost connection fails now, not at its timeout."""
        if connected or self._client is None:
            return
        future = self._client.ctx.response_future
        if not future.done():
            future.set_exception(LinkLost("the device closed the connection", status="BadNotConnected"))

    async def read(self, table: Table, start: int, count: int) -> list[int]:
        """`count` registers (or bits, as 0/1) of `table` from `start`."""
        function = _READ[table]
        what = f"FC{function} {table.value}:{start}-{start + count - 1}"
        client = self._ready()
        calls = {
            Table.COIL: client.read_coils,
            Table.DISCRETE: client.read_discrete_inputs,
            Table.HOLDING: client.read_holding_registers,
            Table.INPUT: client.read_input_registers,
        }
        response = await self._call(what, calls[table](start, count=count, device_id=self.unit))
        if response.function_code != function:
            raise Unexpected(f"{what}: the device answered function {response.function_code}")
        if table.bits:
            bits = response.bits
            if len(bits) < count:
                raise Unexpected(f"{what}: the device answered {len(bits)} of {count} bits")
            return [int(b) for b in bits[:count]]
        registers = response.registers
        if len(registers) != count:
            raise Unexpected(f"{what}: the device answered {len(registers)} of {count} registers")
        return cast(list[int], registers) if isinstance(registers, list) else list(registers)

    async def write(self, table: Table, start: int, values: Sequence[int], *, multiple: bool) -> None:
        """Coils (FC 5 or 15) or holding registers (FC 6 or 16) from `start`."""
        client = self._ready()
        single = len(values) == 1 and not multiple
        if table is Table.COIL:
            function = 5 if single else 15
            bits = [bool(v) for v in values]
            call = (
                client.write_coil(start, bits[0], device_id=self.unit)
                if single
                else client.write_coils(start, bits, device_id=self.unit)
            )
        else:
            function = 6 if single else 16
            call = (
                client.write_register(start, values[0], device_id=self.unit)
                if single
                else client.write_registers(start, list(values), device_id=self.unit)
            )
        what = f"FC{function} {table.value}:{start}" + (
            f"-{start + len(values) - 1}" if len(values) > 1 else ""
        )
        response = await self._call(what, call)
        if response.function_code != function:
            raise Unexpected(f"{what}: the device answered function {response.function_code}")

    def _ready(self) -> AsyncModbusTcpClient:
        client = self._client
        if client is None or not client.connected:
            raise LinkLost(f"not connected to {self.host}:{self.port}", status="BadNotConnected")
        return client

    async def _call(self, what: str, call: Any) -> ModbusPDU:
        self.requests += 1
        try:
            response: ModbusPDU = await call
            deliver_cancel()  # a cancel pymodbus' wait_for swallowed (Python 3.11)
        except LinkLost:
            raise
        except ModbusException as exc:
            guard = self._guard
            if guard is not None and guard.garbled:
                raise LinkLost(f"{what}: {guard.garbled}", status="BadCommunicationError") from None
            if not self.connected:
                raise LinkLost(f"{what}: the connection was lost", status="BadNotConnected") from None
            hint = f"; dropped {guard.last_drop}" if guard is not None and guard.last_drop else ""
            raise LinkLost(f"{what}: no answer within {self.timeout:g} s{hint}", status="BadTimeout") from exc
        except (TimeoutError, OSError) as exc:
            raise LinkLost(f"{what}: {exc or type(exc).__name__}", status="BadNotConnected") from None
        if response.isError():
            raise DeviceRefused(response.function_code & 0x7F, getattr(response, "exception_code", 0), what)
        return response
