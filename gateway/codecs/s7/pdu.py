"""S7comm Read Var and Write Var, many variables a request, planned within the PDU size the PLC negotiated.

The plan: a polling group's fields are coalesced per area and data block into items (contiguous or up to
`max_gap` bytes apart, each as large as a response may carry), and the items packed into as few requests
as fit the PDU both ways: the request (10-byte header, 2 bytes of parameters, 12 per item) and the
response (12-byte header, 2, and per item 4 bytes, its data and a fill byte after an odd length, but the
last). At most `max_items` items a request (20: what S7-300/400 CPUs take). A field larger than one
response can carry is in `too_large`, read by nothing (the loader refuses it for the configured PDU size;
a PLC that negotiates less gets it reported Bad).

The PDUs: every request carries a sequence number the answer must echo. An answer whose header carries
an error (class and code) refused the whole request (`S7Refused`); otherwise each item has its return
code: 0xFF with its bytes, or the reason it failed. Malformed answers are `S7ProtocolError`. Pure.
"""

from __future__ import annotations

import struct
from collections.abc import Collection, Hashable, Sequence
from dataclasses import dataclass, field
from typing import Generic, TypeVar

from gateway.codecs.s7.address import Area, Field
from gateway.errors import CodecError

K = TypeVar("K", bound=Hashable)

REQUEST_HEADER = 10
RESPONSE_HEADER = 12
ITEM_SPEC = 12
MAX_ITEMS = 20
READ_VAR = 0x04
WRITE_VAR = 0x05

# Item return codes (what a Read Var or Write Var item answers), with the status its variables get.
RETURN_CODES: dict[int, tuple[str, str]] = {
    0x01: ("hardware fault", "BadDeviceFailure"),
    0x03: ("access to the object not allowed", "BadUserAccessDenied"),
    0x05: ("address out of range", "BadNodeIdUnknown"),
    0x06: ("data type not supported", "BadTypeMismatch"),
    0x07: ("data type inconsistent", "BadTypeMismatch"),
    0x0A: ("object does not exist", "BadNodeIdUnknown"),
}
# Header errors (class << 8 | code) seen from real CPUs, with what to do about them.
HEADER_ERRORS: dict[int, str] = {
    0x8104: "the CPU refuses the service (S7-1200/1500: allow PUT/GET access in the CPU's protection "
    "settings, and turn off optimized block access for the data blocks read)",
    0x8500: "the request does not fit the negotiated PDU",
    0x8301: "the CPU lacks the resources for the request",
    0xD602: "protection: a password is needed",
}


def return_code_name(code: int) -> str:
    return RETURN_CODES.get(code, (f"return code {code:#04x}", ""))[0]


def return_code_status(code: int) -> str:
    return RETURN_CODES.get(code, ("", "BadCommunicationError"))[1] or "BadCommunicationError"


class S7ProtocolError(CodecError):
    """An answer that is not the answer to the request (malformed, another sequence, another function)."""


class S7Refused(CodecError):
    """The PLC refused the whole request (an error class and code in the answer's header)."""

    def __init__(self, code: int) -> None:
        self.code = code
        known = HEADER_ERRORS.get(code)
        super().__init__(f"error {code:#06x}" + (f": {known}" if known else ""))


# --- the plan ----------------------------------------------------------------------------------------


@dataclass(frozen=True, slots=True)
class Item(Generic[K]):
    """`size` bytes of an area (a data block's) from `start`, and the fields it brings, with offsets."""

    area: Area
    db: int
    start: int
    size: int
    fields: tuple[tuple[K, Field, int], ...]

    def describe(self) -> str:
        where = f"DB{self.db}" if self.area is Area.DB else self.area.prefix
        count = len(self.fields)
        plural = "s" if count != 1 else ""
        return f"{where} bytes {self.start}-{self.start + self.size - 1} ({count} variable{plural})"


@dataclass(frozen=True, slots=True)
class ReadRequest(Generic[K]):
    items: tuple[Item[K], ...]

    @property
    def response_size(self) -> int:
        return response_size([i.size for i in self.items])


@dataclass(slots=True)
class Plan(Generic[K]):
    requests: list[ReadRequest[K]] = field(default_factory=list)
    too_large: list[tuple[K, Field]] = field(default_factory=list)


def response_size(sizes: Sequence[int]) -> int:
    total = RESPONSE_HEADER + 2
    for index, size in enumerate(sizes):
        total += 4 + size + (1 if size % 2 and index < len(sizes) - 1 else 0)
    return total


def max_item(pdu_size: int) -> int:
    """The most bytes one item of a response can carry."""
    return pdu_size - RESPONSE_HEADER - 2 - 4


def plan(
    fields: Sequence[tuple[K, Field]],
    pdu_size: int,
    *,
    max_gap: int = 8,
    max_items: int = MAX_ITEMS,
    isolated: Collection[K] = (),
) -> Plan[K]:
    """The requests that read every field (but those too large for one item)."""
    out: Plan[K] = Plan()
    biggest = max_item(pdu_size)
    alone = set(isolated)
    items: list[Item[K]] = []
    ordered = sorted(fields, key=lambda kf: (kf[1].area, kf[1].db, kf[1].start, kf[1].end))
    current: list[tuple[K, Field]] = []
    start = end = 0

    def close() -> None:
        if current:
            first = current[0][1]
            items.append(Item(first.area, first.db, start, end - start,
                              tuple((k, f, f.start - start) for k, f in current)))  # fmt: skip

    for key, f in ordered:
        if f.size > biggest:
            out.too_large.append((key, f))
            continue
        if key in alone:
            close()
            current = []
            items.append(Item(f.area, f.db, f.start, f.size, ((key, f, 0),)))
            continue
        if current:
            first = current[0][1]
            same = f.area is first.area and f.db == first.db
            if same and f.start - end <= max_gap and max(end, f.end) - start <= biggest:
                current.append((key, f))
                end = max(end, f.end)
                continue
            close()
        current = [(key, f)]
        start, end = f.start, f.end
    close()
    batch: list[Item[K]] = []
    for item in items:
        trial = [*batch, item]
        fits = (
            len(trial) <= max_items
            and REQUEST_HEADER + 2 + ITEM_SPEC * len(trial) <= pdu_size
            and response_size([i.size for i in trial]) <= pdu_size
        )
        if batch and not fits:
            out.requests.append(ReadRequest(tuple(batch)))
            batch = [item]
        else:
            batch = trial
    if batch:
        out.requests.append(ReadRequest(tuple(batch)))
    return out


# --- the PDUs ----------------------------------------------------------------------------------------


def _spec(transport: int, count: int, area: Area, db: int, bit_address: int) -> bytes:
    return struct.pack(">BBBBHHB", 0x12, 0x0A, 0x10, transport, count, db, area) + bit_address.to_bytes(
        3, "big"
    )


def read_request(sequence: int, items: Sequence[tuple[Area, int, int, int]]) -> bytes:
    """Read Var for (area, db, start byte, size) items, as bytes (transport size BYTE)."""
    params = bytes((READ_VAR, len(items))) + b"".join(
        _spec(0x02, size, area, db, start * 8) for area, db, start, size in items
    )
    return struct.pack(">BBHHHH", 0x32, 0x01, 0, sequence & 0xFFFF, len(params), 0) + params


def write_request(
    sequence: int, area: Area, db: int, start: int, data: bytes, bit: int | None = None
) -> bytes:
    """Write Var of one item: bytes from `start`, or (with `bit`) one bit, whose value is data[0]."""
    if bit is None:
        spec = _spec(0x02, len(data), area, db, start * 8)
        body = struct.pack(">BBH", 0x00, 0x04, len(data) * 8) + data
    else:
        spec = _spec(0x01, 1, area, db, start * 8 + bit)
        body = struct.pack(">BBH", 0x00, 0x03, 1) + bytes((1 if data[0] else 0,))
    params = bytes((WRITE_VAR, 1)) + spec
    return struct.pack(">BBHHHH", 0x32, 0x01, 0, sequence & 0xFFFF, len(params), len(body)) + params + body


def _answer(pdu: bytes, sequence: int, function: int, count: int) -> tuple[bytes, int]:
    """The data section of an answer to `function` with `count` items, checked; and where it starts."""
    if len(pdu) < RESPONSE_HEADER:
        raise S7ProtocolError(f"an answer of {len(pdu)} bytes is shorter than its header")
    protocol, kind, _, echoed, params, data, error_class, error_code = struct.unpack_from(">BBHHHHBB", pdu)
    if protocol != 0x32:
        raise S7ProtocolError(f"protocol id {protocol:#04x} is not S7comm (0x32)")
    if kind not in (0x02, 0x03):
        raise S7ProtocolError(f"PDU type {kind} is not an answer")
    if echoed != sequence & 0xFFFF:
        raise S7ProtocolError(f"an answer to request {echoed}, not to {sequence & 0xFFFF}")
    if error_class or error_code:
        raise S7Refused(error_class << 8 | error_code)
    if RESPONSE_HEADER + params + data != len(pdu):
        raise S7ProtocolError(f"lengths {params}+{data} disagree with the answer's {len(pdu)} bytes")
    if params < 2 or pdu[RESPONSE_HEADER] != function:
        raise S7ProtocolError(f"an answer to another function than {function:#04x}")
    if pdu[RESPONSE_HEADER + 1] != count:
        raise S7ProtocolError(f"{pdu[RESPONSE_HEADER + 1]} items answered, {count} asked")
    return pdu, RESPONSE_HEADER + params


def parse_read_response(pdu: bytes, sequence: int, sizes: Sequence[int]) -> list[bytes | int]:
    """Each item's bytes, or its return code where it failed."""
    data, at = _answer(pdu, sequence, READ_VAR, len(sizes))
    out: list[bytes | int] = []
    for index, size in enumerate(sizes):
        if at + 4 > len(data):
            raise S7ProtocolError(f"item {index} of {len(sizes)} is missing")
        code, transport, length = struct.unpack_from(">BBH", data, at)
        at += 4
        if code != 0xFF:
            out.append(code)
            if length:  # a failed item carries no data; skip what it claims all the same
                at += (length + 7) // 8 if transport in (0x03, 0x04, 0x05) else length
            continue
        count = (length + 7) // 8 if transport in (0x03, 0x04, 0x05) else length
        if count != size:
            raise S7ProtocolError(f"item {index}: {count} bytes answered, {size} asked")
        if at + count > len(data):
            raise S7ProtocolError(f"item {index} is cut short")
        out.append(bytes(data[at : at + count]))
        at += count
        if count % 2 and index < len(sizes) - 1:
            at += 1
    return out


def parse_write_response(pdu: bytes, sequence: int) -> int:
    """The return code of a one-item Write Var (0xFF: written)."""
    data, at = _answer(pdu, sequence, WRITE_VAR, 1)
    if at >= len(data):
        raise S7ProtocolError("the write's answer has no return code")
    return data[at]
