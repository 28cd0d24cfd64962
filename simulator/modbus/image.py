"""A Modbus device's four tables as the face serves them, and its answers to parsed requests.

Reads and writes outside a table's size are ILLEGAL DATA ADDRESS, as on a real device; a write to a
register or coil that is not writable is ILLEGAL DATA ADDRESS too, and a write hook may refuse a value
(ILLEGAL DATA VALUE). Pure: the face (face.py) does the I/O, the chiller (chiller.py) fills the tables.
"""

from __future__ import annotations

from collections.abc import Callable, Collection, Sequence

from gateway.codecs.modbus.address import Table
from gateway.codecs.modbus.frames import (
    ExceptionCode,
    Read,
    Refused,
    Request,
    WriteBits,
    WriteRegisters,
    read_bits_response,
    read_registers_response,
    write_response,
)

#: Called with the table, the first address and the values of an accepted write, before it is stored;
#: raising Refused turns the write down.
WriteHook = Callable[[Table, int, Sequence[int]], None]

_READ_TABLE = {1: Table.COIL, 2: Table.DISCRETE, 3: Table.HOLDING, 4: Table.INPUT}


class RegisterImage:
    def __init__(
        self,
        *,
        coils: int = 0,
        discrete: int = 0,
        inputs: int = 0,
        holding: int = 0,
        writable: Collection[tuple[Table, int]] = (),
        on_write: WriteHook | None = None,
    ) -> None:
        self.tables: dict[Table, list[int]] = {
            Table.COIL: [0] * coils,
            Table.DISCRETE: [0] * discrete,
            Table.INPUT: [0] * inputs,
            Table.HOLDING: [0] * holding,
        }
        self.writable = frozenset(writable)
        self.on_write = on_write
        self.reads = 0
        self.writes = 0

    def set(self, table: Table, address: int, values: Sequence[int]) -> None:
        """The device itself changes its values (not a client's write)."""
        self.tables[table][address : address + len(values)] = values

    def get(self, table: Table, address: int, count: int = 1) -> list[int]:
        return self.tables[table][address : address + count]

    def answer(self, request: Request) -> bytes:
        """The response PDU to a parsed request; Refused for one the device turns down."""
        if isinstance(request, Read):
            table = _READ_TABLE[request.function]
            values = self._span(request.function, table, request.address, request.count)
            self.reads += 1
            if table.bits:
                return read_bits_response(request.function, [bool(v) for v in values])
            return read_registers_response(request.function, values)
        table = Table.COIL if isinstance(request, WriteBits) else Table.HOLDING
        values = [int(v) for v in request.values]
        self._span(request.function, table, request.address, len(values))
        for address in range(request.address, request.address + len(values)):
            if (table, address) not in self.writable:
                raise Refused(
                    request.function,
                    ExceptionCode.ILLEGAL_DATA_ADDRESS,
                    f"{table.value}:{address} is read-only",
                )
        if self.on_write is not None:
            self.on_write(table, request.address, values)
        self.set(table, request.address, values)
        self.writes += 1
        assert isinstance(request, (WriteBits, WriteRegisters))
        return write_response(request)

    def _span(self, function: int, table: Table, address: int, count: int) -> list[int]:
        values = self.tables[table]
        if address + count > len(values):
            raise Refused(
                function,
                ExceptionCode.ILLEGAL_DATA_ADDRESS,
                f"{table.value}:{address}-{address + count - 1} is not on this device ({len(values)})",
            )
        return values[address : address + count]
