"""A polling group's fields coalesced into as few read requests as the device allows.

Per table, the fields sorted by address are taken into one request while the next one starts at most
`max_gap` registers (`max_bit_gap` bits) after what the request already covers and the request stays
within `max_registers` (`max_bits`): the specification's 125 registers and 2,000 bits by default.
Going through the fields in order and extending the request as far as the rules allow gives the
fewest requests for those rules. The registers of a gap are read and ignored; a device that refuses
reads across unmapped addresses gets `max_gap: 0`.

`isolated` fields get a request of their own, and no other request reads across them: the driver
isolates the fields of a request the device refused with ILLEGAL DATA ADDRESS, so that the one bad
address (or the hole between two fields that the device will not read) is found and its neighbours
are read again. `cnc-gateway check` prints the plan (`describe`).
"""

from __future__ import annotations

from collections.abc import Collection, Hashable, Sequence
from dataclasses import dataclass
from typing import Generic, TypeVar

from gateway.codecs.modbus.address import MAX_BITS, MAX_REGISTERS, Field, Table

K = TypeVar("K", bound=Hashable)


@dataclass(frozen=True, slots=True)
class Limits:
    max_registers: int = MAX_REGISTERS
    max_bits: int = MAX_BITS
    max_gap: int = 16  # registers read and thrown away to save a request
    max_bit_gap: int = 256

    def size(self, table: Table) -> int:
        return self.max_bits if table.bits else self.max_registers

    def gap(self, table: Table) -> int:
        return self.max_bit_gap if table.bits else self.max_gap


@dataclass(frozen=True, slots=True)
class Request(Generic[K]):
    """One read: `count` registers (or bits) of `table` from `start`, and the fields it brings, with their
    offsets into the response."""

    table: Table
    start: int
    count: int
    fields: tuple[tuple[K, Field, int], ...]  # (key, field, offset into the response)

    @property
    def end(self) -> int:
        return self.start + self.count

    @property
    def function(self) -> int:
        """The Modbus function code that reads it."""
        return _READ_FUNCTION[self.table]

    def describe(self) -> str:
        unit = ("bit" if self.table.bits else "register") + ("s" if self.count != 1 else "")
        used = len({(f.start, f.count) for _, f, _ in self.fields})
        return (
            f"FC{self.function:<2} {self.table.value}:{self.start}-{self.end - 1} ({self.count} {unit}, "
            f"{len(self.fields)} variable{'s' if len(self.fields) != 1 else ''}"
            + (f", {used} distinct" if used != len(self.fields) else "")
            + ")"
        )


_READ_FUNCTION = {Table.COIL: 1, Table.DISCRETE: 2, Table.HOLDING: 3, Table.INPUT: 4}


def plan(
    fields: Sequence[tuple[K, Field]], limits: Limits = Limits(), isolated: Collection[K] = ()
) -> list[Request[K]]:
    """The requests that read every field, per table in address order. A field larger than one request
    allows raises ValueError (the loader refuses such mappings first)."""
    requests: list[Request[K]] = []
    ordered = sorted(fields, key=lambda kf: (kf[1].table.value, kf[1].start, kf[1].end))
    alone = set(isolated)
    current: list[tuple[K, Field]] = []
    start = end = 0
    for key, field in ordered:
        size = limits.size(field.table)
        if field.count > size:
            raise ValueError(f"{field.describe()} is larger than one request may be ({size})")
        if key in alone:  # a request of its own, and no other request reads across it
            if current:
                requests.append(_request(current[0][1].table, start, end, current))
                current = []
            requests.append(_request(field.table, field.start, field.end, [(key, field)]))
            continue
        if current:
            table = current[0][1].table
            fits = (
                field.table is table
                and field.start - end <= limits.gap(table)
                and max(end, field.end) - start <= size
            )
            if fits:
                current.append((key, field))
                end = max(end, field.end)
                continue
            requests.append(_request(table, start, end, current))
        current = [(key, field)]
        start, end = field.start, field.end
    if current:
        requests.append(_request(current[0][1].table, start, end, current))
    return requests


def _request(table: Table, start: int, end: int, members: list[tuple[K, Field]]) -> Request[K]:
    return Request(table, start, end - start, tuple((k, f, f.start - start) for k, f in members))


def describe(requests: Sequence[Request[K]]) -> list[str]:
    """One line per request, as `cnc-gateway check` prints a polling group's plan."""
    return [r.describe() for r in requests]
