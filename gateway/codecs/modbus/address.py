"""A Modbus variable's `source`, parsed strictly, and resolved against its type into a `Field`.

```
holding:100                 holding register 100 (0-based); the type follows the variable's
40101                       the same, in the 40001 style (1-based; the first digit names the table)
holding:100:float32         with the Modbus type
holding:100:float32:CDAB    and the word/byte order of this variable (else the device's)
holding:3.5                 bit 5 of holding register 3 (0 = least significant)
holding:200:string[8]       8 registers, 16 characters
input:0:int32   coil:7   discrete:12   (and hr, ir, co, di; 0xxxx, 1xxxx, 3xxxx, 4xxxx, six digits too)
```

Orders name the bytes of a 32-bit value A (most significant) to D as they come in the registers:
ABCD big-endian, CDAB words swapped, BADC bytes swapped in each word, DCBA both. For 64-bit values
the same two choices apply to four words; a 16-bit value only knows the byte swap; a string only
its byte swap (its characters' order within each register).

The 40001 form is accepted and reported back 0-based (`str(address)`), so that what `check`
prints is what goes on the wire. Errors are `ModbusAddressError` (a CodecError) with the reason.
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from enum import Enum

from gateway.codecs.overlap import overlaps as shared
from gateway.errors import CodecError

MAX_ADDRESS = 65535
MAX_REGISTERS = 125  # per read (the specification's limit for FC 3 and 4)
MAX_BITS = 2000  # per read (FC 1 and 2)


class ModbusAddressError(CodecError):
    """A `source` that is not a usable Modbus address for its variable."""


class Table(str, Enum):
    COIL = "coil"
    DISCRETE = "discrete"
    INPUT = "input"
    HOLDING = "holding"

    @property
    def bits(self) -> bool:
        """Coils and discrete inputs hold bits; the other two tables 16-bit registers."""
        return self in (Table.COIL, Table.DISCRETE)

    @property
    def writable(self) -> bool:
        return self in (Table.COIL, Table.HOLDING)

    @property
    def limit(self) -> int:
        return MAX_BITS if self.bits else MAX_REGISTERS


_TABLE_NAMES: dict[str, Table] = {
    "coil": Table.COIL, "coils": Table.COIL, "co": Table.COIL,
    "discrete": Table.DISCRETE, "discrete_input": Table.DISCRETE, "di": Table.DISCRETE,
    "input": Table.INPUT, "input_register": Table.INPUT, "ir": Table.INPUT,
    "holding": Table.HOLDING, "holding_register": Table.HOLDING, "hr": Table.HOLDING,
}  # fmt: skip
_MODICON: dict[str, Table] = {"0": Table.COIL, "1": Table.DISCRETE, "3": Table.INPUT, "4": Table.HOLDING}


class Kind(str, Enum):
    BOOL = "bool"  # a coil or discrete input
    BIT = "bit"  # one bit of a register
    INT16 = "int16"
    UINT16 = "uint16"
    INT32 = "int32"
    UINT32 = "uint32"
    INT64 = "int64"
    UINT64 = "uint64"
    FLOAT32 = "float32"
    FLOAT64 = "float64"
    STRING = "string"

    @property
    def registers(self) -> int:
        """Registers a value of this kind takes (strings: per their length; bits: 1)."""
        return _REGISTERS.get(self, 1)

    @property
    def integer(self) -> bool:
        return self in _INTEGER

    @property
    def numeric(self) -> bool:
        return self in _INTEGER or self in (Kind.FLOAT32, Kind.FLOAT64)


_REGISTERS = {Kind.INT32: 2, Kind.UINT32: 2, Kind.FLOAT32: 2, Kind.INT64: 4, Kind.UINT64: 4, Kind.FLOAT64: 4}
_INTEGER = frozenset({Kind.INT16, Kind.UINT16, Kind.INT32, Kind.UINT32, Kind.INT64, Kind.UINT64})
_KIND_NAMES = {k.value: k for k in Kind if k not in (Kind.BIT, Kind.STRING)}


class Order(str, Enum):
    ABCD = "ABCD"
    CDAB = "CDAB"
    BADC = "BADC"
    DCBA = "DCBA"

    @property
    def words_swapped(self) -> bool:
        """The least significant word comes first."""
        return self in (Order.CDAB, Order.DCBA)

    @property
    def bytes_swapped(self) -> bool:
        """The low byte of each register comes first."""
        return self in (Order.BADC, Order.DCBA)


# What a variable of each type (its OPC UA type name) is on the device when its source names no Modbus type.
_DEFAULT_KIND: dict[str, Kind] = {
    "SByte": Kind.INT16, "Byte": Kind.UINT16, "Int16": Kind.INT16, "UInt16": Kind.UINT16,
    "Int32": Kind.INT32, "UInt32": Kind.UINT32, "Int64": Kind.INT64, "UInt64": Kind.UINT64,
    "Float": Kind.FLOAT32, "Double": Kind.FLOAT64,
}  # fmt: skip
_WHOLE = frozenset({"SByte", "Byte", "Int16", "UInt16", "Int32", "UInt32", "Int64", "UInt64"})

_STRING_RE = re.compile(r"^string\s*[\[(]\s*(\d+)\s*[\])]$")
_PLACE_RE = re.compile(r"^(\d+)(?:\.(\d+))?$")


@dataclass(frozen=True, slots=True)
class ModbusAddress:
    """A parsed `source`: table, 0-based address, and what the source itself says of the layout."""

    table: Table
    address: int
    bit: int | None = None
    kind: Kind | None = None
    length: int | None = None  # registers of a string
    order: Order | None = None

    def __str__(self) -> str:
        text = f"{self.table.value}:{self.address}"
        if self.bit is not None:
            text += f".{self.bit}"
        if self.kind is Kind.STRING:
            text += f":string[{self.length}]"
        elif self.kind is not None and self.kind not in (Kind.BIT, Kind.BOOL):
            text += f":{self.kind.value}"
        if self.order is not None:
            text += f":{self.order.value}"
        return text


@dataclass(frozen=True, slots=True)
class Field:
    """Where a variable's value is and how it is laid out: what the planner and the codec work on."""

    table: Table
    start: int  # first register (or bit)
    count: int  # registers (or bits) it takes
    kind: Kind
    order: Order = Order.ABCD
    bit: int | None = None
    as_float: bool = False  # the variable's raw type is Float/Double: integers are handed over as floats

    @property
    def end(self) -> int:
        return self.start + self.count

    def describe(self) -> str:
        """`holding:100 float32 CDAB` (registers 100-101), as `check` and errors print it."""
        where = f"{self.table.value}:{self.start}" + (f".{self.bit}" if self.bit is not None else "")
        kind = f"string[{self.count}]" if self.kind is Kind.STRING else self.kind.value
        order = f" {self.order.value}" if self.kind.registers > 1 or self.kind is Kind.STRING else ""
        unit = {Table.COIL: "coil", Table.DISCRETE: "discrete input"}.get(self.table, "register")
        span = f"{unit} {self.start}" if self.count == 1 else f"{unit}s {self.start}-{self.end - 1}"
        return f"{where} {kind}{order} ({span})"


def parse_address(text: str) -> ModbusAddress:
    """Parse a `source`, or raise ModbusAddressError saying what is wrong with it."""
    if not isinstance(text, str) or not text.strip():
        raise ModbusAddressError("a Modbus address must not be empty; e.g. holding:100 or 40101")
    parts = [p.strip() for p in text.strip().split(":")]
    head = parts[0].lower()
    if head in _TABLE_NAMES:
        if len(parts) < 2 or not parts[1]:
            raise ModbusAddressError(f"{text!r} names the table but no address; e.g. {head}:100")
        table = _TABLE_NAMES[head]
        address, bit = _place(parts[1], text)
        rest = parts[2:]
    elif head[:1].isdigit():
        table, address, bit = _modicon(parts[0], text)
        rest = parts[1:]
    else:
        names = "holding, input, coil, discrete (or hr, ir, co, di)"
        raise ModbusAddressError(f"{text!r}: {parts[0]!r} is not a Modbus table; expected {names}")
    kind: Kind | None = None
    length: int | None = None
    order: Order | None = None
    for token in rest:
        upper = token.upper()
        if upper in Order.__members__:
            if order is not None:
                raise ModbusAddressError(f"{text!r} gives two word orders")
            order = Order(upper)
            continue
        if kind is not None:
            raise ModbusAddressError(
                f"{text!r}: {token!r} is neither an order (ABCD, CDAB, BADC, DCBA) nor the only type"
            )
        kind, length = _kind(token, text)
    if table.bits:
        if bit is not None:
            raise ModbusAddressError(f"{text!r}: a {table.value} is a single bit already; drop the .{bit}")
        if kind not in (None, Kind.BOOL) or order is not None:
            raise ModbusAddressError(f"{text!r}: a {table.value} holds one bit; it has no type or order")
        kind = Kind.BOOL if kind is None else kind
    else:
        if kind is Kind.BOOL and bit is None:
            raise ModbusAddressError(
                f"{text!r}: a register holds 16 bits; name one as {table.value}:{address}.<bit> (0-15)"
            )
        if bit is not None:
            if kind not in (None, Kind.BOOL) or order is not None:
                raise ModbusAddressError(f"{text!r}: a bit of a register has no other type or order")
            kind = Kind.BIT
    result = ModbusAddress(table, address, bit, kind, length, order)
    span = length if kind is Kind.STRING and length is not None else (kind.registers if kind else 1)
    if address + span - 1 > MAX_ADDRESS:
        raise ModbusAddressError(
            f"{text!r}: {span} registers from {address} reach {address + span - 1}, past {MAX_ADDRESS}"
        )
    return result


def _place(text: str, whole: str) -> tuple[int, int | None]:
    match = _PLACE_RE.match(text)
    if match is None:
        raise ModbusAddressError(f"{whole!r}: {text!r} is not an address (a number, or number.bit)")
    address = int(match.group(1))
    if address > MAX_ADDRESS:
        raise ModbusAddressError(
            f"{whole!r}: address {address} is past {MAX_ADDRESS}, the last Modbus address"
        )
    bit = match.group(2)
    if bit is not None and int(bit) > 15:
        raise ModbusAddressError(f"{whole!r}: bit {bit} is not in a 16-bit register (0-15)")
    return address, None if bit is None else int(bit)


def _modicon(text: str, whole: str) -> tuple[Table, int, int | None]:
    """The 40001 style: five digits (40001-49999) or six (400001-465536), 1-based, table first."""
    number, _, bit_text = text.partition(".")
    if not number.isdigit() or len(number) not in (5, 6) or number[0] not in _MODICON:
        raise ModbusAddressError(
            f"{whole!r} is not an address: give the table (holding:100, input:5, coil:7, discrete:3) "
            "or the 1-based 40001 style (0xxxx coils, 1xxxx discrete inputs, 3xxxx input registers, "
            "4xxxx holding registers; six digits for addresses past 9999)"
        )
    table = _MODICON[number[0]]
    one_based = int(number[1:])
    if one_based == 0:
        raise ModbusAddressError(f"{whole!r}: the 40001 style counts from 1 ({number[0]}0001 is address 0)")
    address = one_based - 1
    if address > MAX_ADDRESS:
        raise ModbusAddressError(f"{whole!r}: address {address} (0-based) is past {MAX_ADDRESS}")
    if bit_text:
        if table.bits:
            raise ModbusAddressError(f"{whole!r}: a {table.value} is a single bit already")
        _, bit = _place(f"{address}.{bit_text}", whole)
        return table, address, bit
    if "." in text:
        raise ModbusAddressError(f"{whole!r}: a bit number must follow the '.'")
    return table, address, None


def _kind(token: str, whole: str) -> tuple[Kind, int | None]:
    lowered = token.lower()
    if lowered in _KIND_NAMES:
        return _KIND_NAMES[lowered], None
    match = _STRING_RE.match(lowered)
    if match is not None:
        length = int(match.group(1))
        if not 1 <= length <= MAX_REGISTERS:
            raise ModbusAddressError(
                f"{whole!r}: a string takes 1 to {MAX_REGISTERS} registers, not {length}"
            )
        return Kind.STRING, length
    if lowered == "string":
        raise ModbusAddressError(f"{whole!r}: a string needs its length in registers: string[8]")
    names = ", ".join(k for k in _KIND_NAMES if k != "bool")
    raise ModbusAddressError(f"{whole!r}: {token!r} is not a Modbus type; expected {names}, string[N]")


def resolve(address: ModbusAddress, raw_type: str, default_order: Order = Order.ABCD) -> Field:
    """The field of a variable whose controller type is `raw_type` (an OPC UA type name, as the mapping's
    `source_type` or `type`: "Float", "Int32[]"); ModbusAddressError if the two do not fit."""
    if raw_type.endswith("[]"):
        raise ModbusAddressError(f"{address}: Modbus variables are scalars; map each element on its own")
    base = raw_type
    kind = address.kind
    if kind is None:
        if base == "Boolean":
            raise ModbusAddressError(
                f"{address}: a Boolean is a coil, a discrete input or a bit of a register "
                f"({address.table.value}:{address.address}.0)"
            )
        if base == "String":
            raise ModbusAddressError(f"{address}: give the string's length in registers: {address}:string[8]")
        if base not in _DEFAULT_KIND:
            raise ModbusAddressError(f"{address}: a {base} has no Modbus layout")
        kind = _DEFAULT_KIND[base]
    if kind in (Kind.BOOL, Kind.BIT):
        if base != "Boolean":
            raise ModbusAddressError(f"{address} is one bit; the variable must be Boolean, not {base}")
    elif kind is Kind.STRING:
        if base != "String":
            raise ModbusAddressError(f"{address} is a string; the variable must be String, not {base}")
    elif base not in _DEFAULT_KIND:
        raise ModbusAddressError(f"{address} is a {kind.value}; a {base} variable cannot hold it")
    elif not kind.integer and base in _WHOLE:
        raise ModbusAddressError(
            f"{address} is a {kind.value}; an {base} variable would lose its fraction "
            f"(make the variable Float or Double, or give source_type)"
        )
    count = address.length if kind is Kind.STRING and address.length is not None else kind.registers
    order = address.order or default_order
    if address.address + count - 1 > MAX_ADDRESS:
        raise ModbusAddressError(
            f"{address}: {count} registers from {address.address} reach past {MAX_ADDRESS}"
        )
    return Field(
        table=address.table,
        start=address.address,
        count=count,
        kind=kind,
        order=order,
        bit=address.bit,
        as_float=base in ("Float", "Double"),
    )


def overlaps(fields: list[Field]) -> list[tuple[int, int]]:
    """(later, earlier) index pairs of fields that share a register or bit (mapping mistakes); bits of one
    register may stand beside each other and beside the register itself, the same bit twice may not."""
    return shared([(f.table, f.start, f.end, f.bit if f.kind is Kind.BIT else None) for f in fields])
