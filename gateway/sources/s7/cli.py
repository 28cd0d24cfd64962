"""`cnc-gateway s7 read HOST DB10.DBD4 DB10.DBX2.3 MW20 …`: values read from a PLC, to write a mapping.

S7 has no browse of a data block's layout over S7comm: this reads the addresses given (typed as in a
mapping's `source`, e.g. `DB10.DBB20:STRING[30]`) in one multi-variable request per PDU, and prints
each as its type says, beside its raw bytes; a width without a type is shown in every type that width
can be (W: INT and WORD; D: REAL, DINT and DWORD). An address the CPU refuses shows its reason.
"""

from __future__ import annotations

import argparse
import asyncio
import sys
from datetime import datetime
from typing import TextIO

from gateway.codecs.s7.address import Kind, S7Address, S7AddressError, parse_address, resolve
from gateway.codecs.s7.layout import S7ValueError, decode
from gateway.codecs.s7.pdu import (
    S7ProtocolError,
    S7Refused,
    parse_read_response,
    plan,
    read_request,
    return_code_name,
)
from gateway.errors import SourceError

# How each width is shown when the address names no type.
_READINGS: dict[int, tuple[str, ...]] = {
    0: ("Boolean",),
    1: ("Byte", "SByte"),
    2: ("Int16", "UInt16"),
    4: ("Float", "Int32", "UInt32"),
}


def register(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    p = sub.add_parser("s7", help="read values from a Siemens S7 PLC by address, to write a mapping")
    verbs = p.add_subparsers(dest="verb", metavar="VERB", required=True)
    read = verbs.add_parser("read", help="read addresses (DB10.DBD4, DB10.DBX2.3, MW20, I0.1, Q4.0, ...)")
    read.add_argument("host")
    read.add_argument("addresses", nargs="+", metavar="ADDRESS")
    read.add_argument("--port", type=int, default=102, help="ISO-on-TCP port (default 102)")
    read.add_argument("--rack", type=int, default=0, help="default 0")
    read.add_argument("--slot", type=int, default=1, help="default 1 (S7-1200/1500); 2 for an S7-300")
    read.add_argument("--timeout", type=float, default=2.0, help="seconds (default 2)")
    read.set_defaults(handler=handle)


def handle(args: argparse.Namespace) -> int:
    try:
        addresses = [parse_address(text) for text in args.addresses]
    except S7AddressError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    try:
        results, pdu = asyncio.run(read(args.host, args.port, args.rack, args.slot, args.timeout, addresses))
    except (SourceError, S7ProtocolError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 1
    print_values(addresses, results, sys.stdout, pdu)
    return 0


def _size(address: S7Address) -> int:
    if address.kind is Kind.STRING:
        return (address.length or 0) + 2
    return address.kind.size if address.kind is not None else max(1, address.width)


async def read(
    host: str, port: int, rack: int, slot: int, timeout: float, addresses: list[S7Address]
) -> tuple[list[bytes | str], int]:
    """Each address's bytes, or the reason the CPU gave for it; and the negotiated PDU size."""
    from gateway.codecs.s7.address import Field
    from gateway.sources.s7.link import S7Link

    link = S7Link(host, port, rack, slot, timeout, 480)
    await link.connect()
    out: dict[int, bytes | str] = {}
    try:
        fields = [(i, Field(a.area, a.db, a.byte, _size(a), Kind.BYTE)) for i, a in enumerate(addresses)]
        planned = plan(fields, link.pdu_size, max_gap=0, isolated=range(len(fields)))
        for index, _ in planned.too_large:
            out[index] = f"larger than the PDU the CPU negotiated ({link.pdu_size})"
        for request in planned.requests:
            sequence = link.next_sequence()
            specs = [(i.area, i.db, i.start, i.size) for i in request.items]
            answer = await link.exchange(read_request(sequence, specs))
            try:
                results = parse_read_response(answer, sequence, [i.size for i in request.items])
            except S7Refused as refused:
                results = [f"refused: {refused}"] * len(request.items)  # type: ignore[list-item]
            for item, result in zip(request.items, results, strict=True):
                out[item.fields[0][0]] = return_code_name(result) if isinstance(result, int) else result
    finally:
        await link.close()
    return [out[i] for i in range(len(addresses))], link.pdu_size


def print_values(addresses: list[S7Address], results: list[bytes | str], out: TextIO, pdu: int) -> None:
    print(f"# PDU {pdu} bytes", file=out)
    width = max(len(str(a)) for a in addresses) + 2
    for address, result in zip(addresses, results, strict=True):
        if isinstance(result, str):
            print(f"{address!s:<{width}}-- {result}", file=out)
            continue
        shown = []
        types = (
            {Kind.BOOL: ("Boolean",), Kind.STRING: ("String",), Kind.DATE_AND_TIME: ("DateTime",)}.get(
                address.kind, ("Double" if address.kind in (Kind.REAL, Kind.LREAL) else "Int64",)
            )
            if address.kind is not None
            else _READINGS[address.width]
        )
        for type_name in types:
            try:
                field = resolve(address, type_name)
                value = decode(field, result)
            except (S7AddressError, S7ValueError) as exc:
                shown.append(f"({exc})")
                continue
            label = field.kind.value
            text = value.isoformat() if isinstance(value, datetime) else repr(value)
            shown.append(f"{label} {text}")
        print(f"{address!s:<{width}}{'  '.join(shown)}   [{result.hex(' ')}]", file=out)
