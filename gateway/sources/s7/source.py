"""The S7 driver (`driver: {type: s7, host, rack, slot, …}`): multi-variable reads, checked writes.

Variables are grouped by `sampling_interval` (gateway/sources/polling.py runs the groups and the
reconnects); at each connect the groups are planned for the PDU size the CPU negotiated
(gateway/codecs/s7/pdu.py): fields coalesced into items, items packed into Read Var requests that fit
the PDU both ways. The time of the answer is the values' source timestamp; an item whose bytes are those
of its last answer is not decoded, and only values that changed go to the tree.

Failures, from narrow to wide:
- an item the CPU answers with an error marks its variables Bad (address out of range and object does
  not exist: BadNodeIdUnknown, access not allowed: BadUserAccessDenied); for an address out of range in
  an item of several variables, they are read one by one from the next cycle on, so only the bad one
  stays Bad; a DATE_AND_TIME whose bytes are not one marks that variable BadDecodingError;
- a request the CPU refuses whole (an error in the answer's header, such as an S7-1200/1500 without
  PUT/GET access) marks its variables Bad with the CPU's reason;
- no answer, a lost connection, or an answer that is not the answer end the connection: every variable
  turns Bad, and the driver reconnects with the shared backoff.

Writes (from the tree's checked write path) are one Write Var item: the field's bytes, or for a BOOL
the bit itself (S7 writes single bits, so nothing else of the byte is touched). A refusal is
`ControllerRefused` with the CPU's reason; then the field is read back for the tree.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, field
from typing import Any, Self

from gateway.codecs.s7.address import Area, Field, Kind
from gateway.codecs.s7.layout import Decoder, S7ValueError, decoder, encode
from gateway.codecs.s7.pdu import (
    Item,
    ReadRequest,
    S7ProtocolError,
    S7Refused,
    parse_read_response,
    parse_write_response,
    plan,
    read_request,
    return_code_name,
    return_code_status,
    write_request,
)
from gateway.errors import ControllerRefused, ControllerUnavailable, SourceError
from gateway.model.sample import ReadBack, utcnow
from gateway.model.tree import Machine, VariableNode
from gateway.sources.base import DriverMapping, settings_of
from gateway.sources.polling import Group, Poller
from gateway.sources.s7.config import S7Driver
from gateway.sources.s7.link import LinkLost, S7Link

log = logging.getLogger("gateway.sources.s7")

_UNSET: Any = object()
_REFUSED_STATUS = {
    0x8104: "BadUserAccessDenied",
    0xD602: "BadUserAccessDenied",
    0x8500: "BadEncodingLimitsExceeded",
}


@dataclass(slots=True)
class _Slot:
    node: VariableNode
    field: Field
    decode: Decoder
    last: Any = _UNSET


@dataclass(slots=True)
class _Item:
    item: Item[VariableNode]
    slots: list[tuple[_Slot, int]]
    last: bytes | None = None
    bad: str | None = None

    def forget(self) -> None:
        self.last = None
        self.bad = None
        for slot, _ in self.slots:
            slot.last = _UNSET


@dataclass(slots=True)
class _Read:
    request: ReadRequest[VariableNode]
    items: list[_Item]
    specs: list[tuple[Area, int, int, int]] = field(default_factory=list)
    sizes: list[int] = field(default_factory=list)


class S7Source(Poller[Field, _Read]):
    def __init__(self, machine: Machine, mapping: DriverMapping) -> None:
        self.driver: S7Driver = settings_of(mapping, S7Driver)
        super().__init__(machine, self.driver, log)
        d = self.driver
        self.link = S7Link(d.host, d.port, d.rack, d.slot, d.timeout, d.pdu_size)
        interval = {var.path: mapping.sampling_interval(var) for var in mapping.variables}
        entries = [(node, node.definition.source, node.definition.raw_type, interval[node.path])
                   for node in machine.mapped]  # fmt: skip
        groups = d.polling_groups(entries)
        self._by_node: dict[VariableNode, _Slot] = {}
        for fields in groups.values():
            for node, spot in fields:
                self._by_node[node] = _Slot(node, spot, decoder(spot))
        self.groups = [Group(ms / 1000.0, fields) for ms, fields in groups.items()]
        self.too_large: list[VariableNode] = []
        for group in self.groups:
            self._plan(group)
        self.values = 0  # variables read (in answered items)
        self.unchanged = 0  # items whose bytes were those of the last answer

    def __repr__(self) -> str:
        return f"<S7Source {self.machine.name} {self.driver.endpoint}>"

    async def __aenter__(self) -> Self:
        self.machine.writer = self
        return self

    async def __aexit__(self, *exc_info: object) -> None:
        if self.machine.writer is self:
            self.machine.writer = None
        await self.stopped()

    def _plan(self, group: Group[Field, _Read]) -> None:
        planned = plan(group.fields, self.link.pdu_size, max_gap=self.driver.max_gap, isolated=group.isolated)
        group.reads = []
        for request in planned.requests:
            items = [
                _Item(i, [(self._by_node[k], offset) for k, _, offset in i.fields]) for i in request.items
            ]
            specs = [(i.area, i.db, i.start, i.size) for i in request.items]
            group.reads.append(_Read(request, items, specs, [i.size for i in request.items]))
        for node, spot in planned.too_large:
            self.too_large.append(node)
            negotiated = self.link.pdu_size
            reason = f"{spot.describe()} is larger than the PDU the CPU negotiated ({negotiated}) can carry"
            self.machine.ingest(node, None, utcnow(), "BadEncodingLimitsExceeded", reason)

    # --- Poller ----------------------------------------------------------------------------------

    async def connect(self) -> None:
        await self.link.connect()
        self.too_large = []
        for group in self.groups:
            self._plan(group)

    async def close(self) -> None:
        await self.link.close()

    def forget(self) -> None:
        for group in self.groups:
            for read in group.reads:
                for item in read.items:
                    item.forget()

    def describe(self) -> str:
        requests = sum(len(g.reads) for g in self.groups)
        return (
            f"PDU {self.link.pdu_size} bytes, {requests} requests a cycle for {len(self._by_node)} variables"
        )

    async def cycle(self, group: Group[Field, _Read]) -> None:
        replan = False
        for read in group.reads:
            sequence = self.link.next_sequence()
            answer = await self.link.exchange(read_request(sequence, read.specs))
            stamp = utcnow()
            try:
                results = parse_read_response(answer, sequence, read.sizes)
            except S7Refused as refused:
                status = _REFUSED_STATUS.get(refused.code, "BadCommunicationError")
                for item in read.items:
                    self._bad(item, status, f"the CPU refused the read: {refused}")
                continue
            except S7ProtocolError as exc:
                raise LinkLost(f"an answer that does not fit the request: {exc}",
                               status="BadCommunicationError") from None  # fmt: skip
            for item, result in zip(read.items, results, strict=True):
                if isinstance(result, int):
                    replan |= self._failed(group, item, result)
                    continue
                self.values += len(item.slots)
                if item.bad is not None:
                    item.forget()
                elif result == item.last:
                    self.unchanged += 1
                    continue
                item.last = result
                self._decode(item, result, stamp)
        if replan:
            self._plan(group)

    def _decode(self, item: _Item, data: bytes, stamp: Any) -> None:
        machine = self.machine
        for slot, offset in item.slots:
            try:
                value = slot.decode(data, offset)
            except S7ValueError as exc:
                if slot.last is not None:
                    slot.last = None
                    machine.ingest(slot.node, None, stamp, "BadDecodingError", str(exc))
                continue
            if value != slot.last:
                slot.last = value
                machine.ingest(slot.node, value, stamp)

    def _failed(self, group: Group[Field, _Read], item: _Item, code: int) -> bool:
        """An item the CPU answered with an error; True if its fields are to be read apart from now on."""
        reason = f"the CPU answered {item.item.describe()}: {return_code_name(code)}"
        distinct = {(f.start, f.size) for _, f, _ in item.item.fields}
        self._bad(item, return_code_status(code), reason)
        if code == 0x05 and len(distinct) > 1:
            group.isolated.update(key for key, _, _ in item.item.fields)
            log.warning("%s: reading the %d variables of %s one by one to find the bad address",
                        self.machine.name, len(item.slots), item.item.describe())  # fmt: skip
            return True
        return False

    def _bad(self, item: _Item, status: str, reason: str) -> None:
        if item.bad == status:
            return
        if item.bad is None:
            log.warning("%s: %s", self.machine.name, reason)
        item.forget()
        item.bad = status
        stamp = utcnow()
        for slot, _ in item.slots:
            self.machine.ingest(slot.node, None, stamp, status, reason)

    # --- writes ----------------------------------------------------------------------------------

    async def write(self, node: VariableNode, raw: Any) -> ReadBack | None:
        slot = self._by_node.get(node)
        if slot is None:  # pragma: no cover - the tree only writes mapped variables
            raise ControllerRefused(f"{node.full_path} is not an S7 variable", status="BadNodeIdUnknown")
        spot = slot.field
        data = encode(spot, raw)
        bit = spot.bit if spot.kind is Kind.BOOL else None
        sequence = self.link.next_sequence()
        try:
            answer = await self.link.exchange(
                write_request(sequence, spot.area, spot.db, spot.start, data, bit)
            )
            code = parse_write_response(answer, sequence)
        except S7Refused as refused:
            status = _REFUSED_STATUS.get(refused.code, "BadWriteNotSupported")
            raise ControllerRefused(
                f"{node.full_path}: the CPU refused the write: {refused}", status=status
            ) from None
        except (SourceError, S7ProtocolError) as exc:
            raise ControllerUnavailable(f"{node.full_path}: {exc}") from None
        if code != 0xFF:
            raise ControllerRefused(
                f"{node.full_path}: the CPU refused {spot.describe()}: {return_code_name(code)}",
                status=return_code_status(code),
            )
        return await self._read_back(slot)

    async def _read_back(self, slot: _Slot) -> ReadBack | None:
        spot = slot.field
        sequence = self.link.next_sequence()
        try:
            answer = await self.link.exchange(
                read_request(sequence, [(spot.area, spot.db, spot.start, spot.size)])
            )
            (result,) = parse_read_response(answer, sequence, [spot.size])
            if isinstance(result, int):
                return None
            return ReadBack(slot.decode(result, 0), utcnow())
        except (SourceError, S7ProtocolError, S7Refused, S7ValueError) as exc:
            log.info("%s: reading %s back after a write failed: %s", self.machine.name, spot.describe(), exc)
            return None
