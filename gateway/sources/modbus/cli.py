"""`cnc-gateway modbus scan HOST --unit 1 --range 0-200`: a device's raw registers in every layout.

Modbus has no browse, so there is nothing to `discover`: this is what one reads to write a mapping. Each
register is printed with its 0-based and 40001-style addresses, its raw word, as uint16 and int16 and as
two characters, and each pair starting there as float32 and int32 in the four word/byte orders (ABCD,
CDAB, BADC, DCBA); `--wide` adds float64 in the four orders. A known value on the device's display
(a temperature, a setpoint) then shows which order the device uses. Reads go in requests of 125
registers (2,000 bits); a request the device refuses is read again register by register, and what it
refuses then is shown as `--` with the exception's name.
"""

from __future__ import annotations

import argparse
import asyncio
import math
import sys
from typing import TextIO

from gateway.codecs.modbus.address import MAX_ADDRESS, Field, Kind, Order, Table
from gateway.codecs.modbus.layout import decode
from gateway.errors import SourceError

_MODICON = {Table.COIL: 0, Table.DISCRETE: 1, Table.INPUT: 3, Table.HOLDING: 4}


def register(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    p = sub.add_parser("modbus", help="read a Modbus TCP device's raw registers, to write a mapping")
    verbs = p.add_subparsers(dest="verb", metavar="VERB", required=True)
    scan = verbs.add_parser("scan", help="print registers in every word/byte order")
    scan.add_argument("host")
    scan.add_argument("--port", type=int, default=502, help="TCP port (default 502)")
    scan.add_argument("--unit", type=int, default=1, help="unit id (default 1)")
    scan.add_argument("--range", dest="span", default="0-99", help="first-last, 0-based (default 0-99)")
    scan.add_argument(
        "--table", choices=[t.value for t in Table], default="holding", help="default: holding registers"
    )
    scan.add_argument("--timeout", type=float, default=2.0, help="seconds per request (default 2)")
    scan.add_argument("--wide", action="store_true", help="also float64 in the four orders")
    scan.set_defaults(handler=handle)


def parse_span(text: str) -> tuple[int, int]:
    first, _, last = text.partition("-")
    try:
        start, end = int(first), int(last or first)
    except ValueError:
        raise ValueError(f"--range {text!r}: give first-last, e.g. 0-200") from None
    if not 0 <= start <= end <= MAX_ADDRESS:
        raise ValueError(f"--range {text!r}: addresses run 0-{MAX_ADDRESS}, first before last")
    return start, end


def handle(args: argparse.Namespace) -> int:
    try:
        start, end = parse_span(args.span)
    except ValueError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    table = Table(args.table)
    try:
        values = asyncio.run(scan(args.host, args.port, args.unit, table, start, end, args.timeout))
    except SourceError as exc:
        print(f"error: {exc.reason}", file=sys.stderr)
        return 1
    print_scan(table, start, values, sys.stdout, wide=args.wide)
    return 0


async def scan(
    host: str, port: int, unit: int, table: Table, start: int, end: int, timeout: float
) -> list[int | str]:
    """Each address's value, or the name of the exception the device answered for it."""
    from gateway.sources.modbus.link import DeviceRefused, ModbusLink

    link = ModbusLink(host, port, unit, timeout)
    await link.connect()
    out: list[int | str] = []
    try:
        size = table.limit
        for first in range(start, end + 1, size):
            count = min(size, end + 1 - first)
            try:
                out += await link.read(table, first, count)
                continue
            except DeviceRefused:
                pass
            for address in range(first, first + count):
                try:
                    out += await link.read(table, address, 1)
                except DeviceRefused as refused:
                    out.append(refused.name)
    finally:
        link.close()
    return out


def _number(value: object) -> str:
    if isinstance(value, float):
        if math.isnan(value) or math.isinf(value):
            return str(value)
        return f"{value:.7g}"
    return str(value)


def _chars(word: int) -> str:
    return "".join(chr(b) if 32 <= b < 127 else "." for b in (word >> 8, word & 0xFF))


def print_scan(table: Table, start: int, values: list[int | str], out: TextIO, *, wide: bool = False) -> None:
    prefix = _MODICON[table]
    if table.bits:
        print(f"{'address':>8} {prefix}xxxxx  value", file=out)
        for offset, value in enumerate(values):
            address = start + offset
            shown = value if isinstance(value, str) else int(value)
            print(f"{address:>8} {prefix}{address + 1:05d}  {shown}", file=out)
        return
    orders = list(Order)
    head = f"{'address':>8} {prefix}xxxxx   hex    uint16  int16 chars"
    head += "".join(f" {'f32 ' + o.value:>14}" for o in orders) + "".join(
        f" {'i32 ' + o.value:>12}" for o in orders
    )
    if wide:
        head += "".join(f" {'f64 ' + o.value:>14}" for o in orders)
    print(head, file=out)
    for offset, value in enumerate(values):
        address = start + offset
        line = f"{address:>8} {prefix}{address + 1:05d}"
        if isinstance(value, str):
            print(f"{line}  -- {value}", file=out)
            continue
        line += (
            f"  0x{value:04X} {value:>7} {value - 0x10000 if value & 0x8000 else value:>6} {_chars(value):>5}"
        )
        pair = values[offset : offset + 2]
        quad = values[offset : offset + 4]
        for kind, width, words in ((Kind.FLOAT32, 14, pair), (Kind.INT32, 12, pair)):
            for order in orders:
                shown = "--"
                if len(words) == 2 and all(isinstance(w, int) for w in words):
                    shown = _number(decode(Field(table, 0, 2, kind, order), [int(w) for w in words]))
                line += f" {shown:>{width}}"
        if wide:
            for order in orders:
                shown = "--"
                if len(quad) == 4 and all(isinstance(w, int) for w in quad):
                    shown = _number(decode(Field(table, 0, 4, Kind.FLOAT64, order), [int(w) for w in quad]))
                line += f" {shown:>14}"
        print(line, file=out)
