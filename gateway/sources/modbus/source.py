"""The Modbus TCP driver (`driver: {type: modbus, host, port, unit, …}`): polling groups, writes, reconnect.

Variables are grouped by their `sampling_interval`; each group's fields are coalesced into requests by
the pure planner (gateway/codecs/modbus/planner.py) once, at start, and the plan is what
`cnc-gateway check` prints. One task polls every group of the device over one connection, each when it
is due (a group whose cycle overran starts its next one at once and counts the overrun; cycles are not
made up). The time of each response is the source timestamp of what it brought, and only changes go to
the tree: a response whose registers are those of the last one is not decoded at all, and of one that
changed, only the variables whose values changed are handed on.

Failures, from narrow to wide:
- an exception response marks the variables of that request Bad (ILLEGAL DATA ADDRESS:
  BadNodeIdUnknown, and the other codes their own status) and the rest of the device stays Good; for
  ILLEGAL DATA ADDRESS on a request of several variables, those variables are read one by one from the
  next cycle on (`Limits`' isolation), so that only the bad address stays Bad;
- an answer that does not fit its request (too few registers) marks that request's variables Bad;
- no answer, a lost connection or garbled bytes end the connection: every variable turns Bad and the
  driver reconnects with the shared backoff (gateway/reconnect.py).

Writes come checked from the tree (role, type, range, scaling: the one write path); a coil is written
with FC 5, a register with FC 6, several registers with FC 16 (FC 15/16 always with `write_multiple`);
a bit of a register is read, changed and written back (FC 3 then 6: the device may change the other
bits in between, which the README says). The device's refusal comes back as `ControllerRefused` with
its name; then the field is read back and the tree takes that value before the write is answered.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass
from typing import Any, Self

from gateway.codecs.modbus.address import Field, Kind, Table
from gateway.codecs.modbus.layout import Decoder, decoder, encode
from gateway.codecs.modbus.planner import Request, plan
from gateway.errors import ControllerRefused, ControllerUnavailable, SourceError
from gateway.model.sample import ReadBack, utcnow
from gateway.model.tree import Machine, VariableNode
from gateway.sources.base import DriverMapping, settings_of
from gateway.sources.modbus.config import ModbusDriver
from gateway.sources.modbus.link import DeviceRefused, LinkLost, ModbusLink
from gateway.sources.polling import Group, Poller

log = logging.getLogger("gateway.sources.modbus")

_UNSET: Any = object()


@dataclass(slots=True)
class _Slot:
    """One variable: its field, its decoder, the last value handed to the tree."""

    node: VariableNode
    field: Field
    decode: Decoder
    last: Any = _UNSET


@dataclass(slots=True)
class _Read:
    """One planned request and what it brings."""

    request: Request[VariableNode]
    slots: list[tuple[_Slot, int]]
    last: list[int] | None = None  # the registers of the last good answer
    bad: str | None = None  # the status of its variables while it fails

    def forget(self) -> None:
        self.last = None
        self.bad = None
        for slot, _ in self.slots:
            slot.last = _UNSET


class ModbusSource(Poller[Field, _Read]):
    def __init__(self, machine: Machine, mapping: DriverMapping) -> None:
        self.driver: ModbusDriver = settings_of(mapping, ModbusDriver)
        super().__init__(machine, self.driver, log)
        d = self.driver
        self.link = ModbusLink(d.host, d.port, d.unit, d.timeout)
        interval = {var.path: mapping.sampling_interval(var) for var in mapping.variables}
        entries = [(node, node.definition.source, node.definition.raw_type, interval[node.path])
                   for node in machine.mapped]  # fmt: skip
        groups = d.polling_groups(entries)
        self._by_node: dict[VariableNode, _Slot] = {}
        for fields in groups.values():
            for node, spot in fields:
                self._by_node[node] = _Slot(node, spot, decoder(spot))
        self.groups = [Group(ms / 1000.0, fields) for ms, fields in groups.items()]
        for group in self.groups:
            self._plan(group)
        self.responses = 0  # answers that carried values
        self.registers = 0  # registers (or bits) those answers brought
        self.unchanged = 0  # of which were the same registers as the last time

    def __repr__(self) -> str:
        return f"<ModbusSource {self.machine.name} {self.driver.endpoint}>"

    async def __aenter__(self) -> Self:
        self.machine.writer = self
        return self

    async def __aexit__(self, *exc_info: object) -> None:
        if self.machine.writer is self:
            self.machine.writer = None
        await self.stopped()

    @property
    def requests_per_cycle(self) -> float:
        """Requests of one cycle of every group, per variable read (the planner's saving)."""
        requests = sum(len(g.reads) for g in self.groups)
        return requests / max(1, len(self._by_node))

    def _plan(self, group: Group[Field, _Read]) -> None:
        group.reads = [
            _Read(request, [(self._by_node[key], offset) for key, _, offset in request.fields])
            for request in plan(group.fields, self.driver.limits, group.isolated)
        ]

    # --- Poller ----------------------------------------------------------------------------------

    async def connect(self) -> None:
        await self.link.connect()

    async def close(self) -> None:
        self.link.close()

    def forget(self) -> None:
        for group in self.groups:
            for read in group.reads:
                read.forget()

    def describe(self) -> str:
        requests = sum(len(g.reads) for g in self.groups)
        return f"{requests} requests a cycle for {len(self._by_node)} variables"

    async def cycle(self, group: Group[Field, _Read]) -> None:
        replan = False
        machine = self.machine
        link = self.link
        for read in group.reads:
            request = read.request
            try:
                values = await link.read(request.table, request.start, request.count)
            except LinkLost:
                raise
            except DeviceRefused as refused:
                replan |= self._refused(group, read, refused)
                continue
            except SourceError as exc:  # an answer that does not fit the request
                self._bad(read, exc.status, exc.reason)
                continue
            stamp = utcnow()
            self.responses += 1
            self.registers += request.count
            if read.bad is not None:
                read.forget()
            elif values == read.last:
                self.unchanged += 1
                continue
            read.last = values
            for slot, offset in read.slots:
                value = slot.decode(values, offset)
                if value != slot.last:
                    slot.last = value
                    machine.ingest(slot.node, value, stamp)
        if replan:
            self._plan(group)

    def _refused(self, group: Group[Field, _Read], read: _Read, refused: DeviceRefused) -> bool:
        """Mark the request's variables Bad; True if the group is to be planned again with them apart."""
        request = read.request
        distinct = {(f.start, f.count) for _, f, _ in request.fields}
        if refused.code == 2 and len(distinct) > 1:
            group.isolated.update(key for key, _, _ in request.fields)
            log.warning("%s: %s refused %s; reading its %d variables one by one to find the address",
                        self.machine.name, self.driver.endpoint, refused.reason,
                        len(request.fields))  # fmt: skip
            self._bad(read, refused.status, f"the device refused {refused.reason}")
            return True
        self._bad(read, refused.status, f"the device refused {refused.reason}")
        return False

    def _bad(self, read: _Read, status: str, reason: str) -> None:
        if read.bad == status:
            return
        if read.bad is None:
            log.warning("%s: %s", self.machine.name, reason)
        read.forget()
        read.bad = status
        stamp = utcnow()
        for slot, _ in read.slots:
            self.machine.ingest(slot.node, None, stamp, status, reason)

    # --- writes ----------------------------------------------------------------------------------

    async def write(self, node: VariableNode, raw: Any) -> ReadBack | None:
        slot = self._by_node.get(node)
        if slot is None:  # pragma: no cover - the tree only writes mapped variables
            raise ControllerRefused(f"{node.full_path} is not a Modbus variable", status="BadNodeIdUnknown")
        spot = slot.field
        link = self.link
        multiple = self.driver.write_multiple
        try:
            if spot.kind is Kind.BIT:
                registers = encode(spot, raw)
                current = (await link.read(Table.HOLDING, spot.start, 1))[0]
                mask = 1 << (spot.bit or 0)
                word = current | mask if registers[0] else current & ~mask & 0xFFFF
                await link.write(Table.HOLDING, spot.start, [word], multiple=multiple)
            else:
                await link.write(spot.table, spot.start, encode(spot, raw), multiple=multiple)
        except DeviceRefused as refused:
            raise ControllerRefused(
                f"{node.full_path}: the device refused {refused.reason}", status=refused.status
            ) from None
        except SourceError as exc:
            raise ControllerUnavailable(f"{node.full_path}: {exc.reason}") from None
        return await self._read_back(slot)

    async def _read_back(self, slot: _Slot) -> ReadBack | None:
        spot = slot.field
        try:
            values = await self.link.read(spot.table, spot.start, spot.count)
        except SourceError as exc:
            log.info("%s: reading %s back after a write failed: %s", self.machine.name, spot.describe(),
                     exc.reason)  # fmt: skip
            return None
        return ReadBack(slot.decode(values, 0), utcnow())
